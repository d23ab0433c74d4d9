"""The simulator's camera family: colour response, white balance, tone curves, chroma sampling, bodies, props."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from edge.camera import paper_camera
from edge.errors import SimulationError
from edge.sim.cameras import BODY_ALBEDOS, draw_bodies, draw_camera, draw_processing
from edge.sim.colour import AutoWhiteBalance, ColourResponse, awb_gains, crosstalk_matrix, tone_encode
from edge.sim.effects import BAYER_PHASES, DEMOSAIC, Compression, Effects, Prop, SignalProcessing
from edge.sim.render import Renderer
from edge.sim.scenarios import SCENARIOS, build
from edge.sim.scene import EIGHT_HUES, FloorLook, Scene, fleet_looks
from edge.sim.sensor import demosaic, jpeg_roundtrip, sharpen_luma
from edge.sim.setup import scenario_rng
from edge.sim.world import WorldState
from tests.support.sim import clean_effects


def _grey_scene(albedo: float = 0.4) -> Scene:
    floor = FloorLook(
        base_bgr=(albedo, albedo, albedo), grout_bgr=(albedo,) * 3, speckle=0.0, tile_variation=0.0, specular=0.0
    )
    return Scene((), floor=floor, tape=None, lamps=(), ambient=1.0)


def _render(effects: Effects, scene: Scene | None = None) -> np.ndarray:
    renderer = Renderer(paper_camera(), scene or _grey_scene(), effects)
    return renderer.render(WorldState(0.0, ()), 0)


@pytest.mark.parametrize("seed", range(12))
def test_every_camera_of_the_family_is_within_the_issues_ranges(seed):
    cam = draw_camera(np.random.default_rng(seed))
    assert cam.compression.chroma in ("4:2:0", "4:2:2", "4:4:4")
    assert 60 <= cam.compression.quality <= 95
    assert 0.3 <= cam.optics.blur_sigma_px <= 1.2
    assert 2.0 <= cam.gamma <= 2.4
    crosstalk = np.asarray(cam.colour.crosstalk)
    assert np.allclose(crosstalk.sum(axis=1), 1.0)
    assert np.all(np.diag(crosstalk) >= 0.6)  # up to 15 % (+-30 %) to each spectral neighbour
    assert all(0.88 <= g <= 1.13 for g in cam.colour.white_balance)
    assert cam.noise.read_noise > 0 and cam.noise.full_well > 0


def test_the_family_draws_every_chroma_sampling_tone_curve_and_body():
    cams = [draw_camera(np.random.default_rng(s)) for s in range(60)]
    assert {c.compression.chroma for c in cams} == {"4:2:0", "4:2:2", "4:4:4"}
    assert {c.colour.tone for c in cams} == {"gamma", "srgb", "bt709"}
    assert any(c.auto_white_balance is not None for c in cams) and any(c.auto_white_balance is None for c in cams)
    greys = set()
    for s in range(20):
        for look in draw_bodies(fleet_looks(3), np.random.default_rng(s)):
            greys.add(min(BODY_ALBEDOS.values(), key=lambda g, b=look.body_bgr: abs(g - sum(b) / 3)))
            assert look.body_length_cm - look.marker_length_cm >= 0.4
            assert 8.0 <= look.body_height_cm <= 20.0
    assert greys == set(BODY_ALBEDOS.values())


def test_a_family_scenario_keeps_one_marker_plane_and_names_its_camera():
    setup = build("lab", seed=4, camera="family")
    heights = {look.body_height_cm for look in setup.scene.rovers}
    assert len(heights) == 1 and setup.marker_height_cm in heights
    assert setup.camera_name != "nominal" and "q" in setup.camera_name
    assert build("lab", seed=4, camera="family").camera_name == setup.camera_name  # seeded
    with pytest.raises(SimulationError, match="--camera"):
        build("lab", seed=4, camera="phone")  # type: ignore[arg-type]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_every_scenario_renders_through_a_family_camera(name):
    setup = build(name, seed=11, frames=3, camera="family")
    renderer = setup.renderer()
    frame = renderer.render(setup.world().state_at(0.5), 15)
    assert frame.shape == (720, 1280, 3) and frame.dtype == np.uint8
    assert all(0 <= c <= 255 for c in setup.rover_configs(renderer)[0].color_bgr)


@pytest.mark.slow
def test_crosstalk_and_white_balance_act_on_linear_light_and_keep_grey_grey():
    grey = _render(clean_effects())
    mixed = _render(Effects(**{**clean_effects().__dict__, "colour": ColourResponse(crosstalk_matrix(0.15))}))
    assert np.abs(grey.astype(int) - mixed.astype(int)).max() <= 1  # rows sum to 1: a grey stays grey
    warm = _render(Effects(**{**clean_effects().__dict__, "colour": ColourResponse(white_balance=(1.0, 1.0, 1.2))}))
    b, g, r = (float(warm[360, 640, k]) for k in range(3))
    b0, _, r0 = (float(grey[360, 640, k]) for k in range(3))
    assert b == pytest.approx(b0, abs=1) and g == pytest.approx(b0, abs=1)
    assert r / r0 == pytest.approx(1.2 ** (1 / 2.2), abs=0.02)  # the gain in linear light, through the tone curve


@pytest.mark.slow
@pytest.mark.parametrize("tone", ["srgb", "bt709"])
def test_tone_curves_encode_linear_light_as_the_standards_say(tone):
    effects = Effects(**{**clean_effects().__dict__, "colour": ColourResponse(tone=tone)})
    renderer = Renderer(paper_camera(), _grey_scene(), effects)
    frame = renderer.render(WorldState(0.0, ()), 0)
    lin = float(renderer._room[360, 640, 1])  # the floor's linear light at the image's centre
    expected = float(tone_encode(np.array([lin]), tone, 2.2)[0]) * 255.0
    assert float(frame[360, 640, 1]) == pytest.approx(expected, abs=1.5)
    assert tone_encode(np.array([0.001]), "srgb", 2.2)[0] == pytest.approx(0.01292, abs=1e-4)
    assert tone_encode(np.array([0.01]), "bt709", 2.2)[0] == pytest.approx(0.045, abs=1e-4)


def test_auto_white_balance_turns_a_warm_cast_grey_with_a_lag():
    warm = np.array([[0.3, 0.4, 0.5]] * 10 + [[0.5, 0.4, 0.3]] * 40)
    gains = awb_gains(warm, AutoWhiteBalance(rate=0.2, delay_frames=2, strength=1.0))
    assert gains[0] == pytest.approx([4 / 3, 1.0, 0.8], rel=1e-6)  # converged on frame 0's cast
    assert gains[11, 0] == pytest.approx(gains[0, 0])  # the change is seen two frames late
    assert gains[-1] == pytest.approx([0.8, 1.0, 4 / 3], rel=0.01)  # and corrected in the end
    assert gains[14, 0] > 0.8 * 1.05  # but not at once


def test_four_two_zero_halves_the_chroma_rows_and_four_two_two_the_columns():
    def spill(axis: int, chroma: str) -> float:
        """Largest change of the pixels just before a red/blue edge along ``axis`` (rows 0, columns 1)."""
        image = np.zeros((32, 32, 3), np.uint8)
        image[...] = (40, 40, 200)
        if axis == 0:
            image[16:, :] = (200, 60, 40)
            near = image[15, 4:28].astype(int), jpeg_roundtrip(image, 95, chroma)[15, 4:28].astype(int)
        else:
            image[:, 16:] = (200, 60, 40)
            near = image[4:28, 15].astype(int), jpeg_roundtrip(image, 95, chroma)[4:28, 15].astype(int)
        return float(np.abs(near[0] - near[1]).max())

    assert spill(0, "4:2:0") > 25 and spill(1, "4:2:0") > 25
    assert spill(0, "4:2:2") < 12 < 25 < spill(1, "4:2:2")
    assert spill(0, "4:4:4") < 12 and spill(1, "4:4:4") < 12
    with pytest.raises(SimulationError, match="chroma"):
        Compression(80, "4:1:1")


@pytest.mark.slow
def test_a_prop_is_put_down_at_its_time_and_hides_the_floor_from_then_on():
    prop = Prop(195.0, 300.0, (40.0, 30.0, 30.0), 0.0, (0.9, 0.9, 0.9), appears_s=1.0)
    effects = Effects(**{**clean_effects().__dict__, "props": (prop,)})
    renderer = Renderer(paper_camera(), _grey_scene(0.2), effects)
    uv = paper_camera().project(np.array([[195.0, 300.0, 30.0]]))[0]
    u, v = round(uv[0]), round(uv[1])
    before = renderer.render(WorldState(0.0, ()), 0)
    after = renderer.render(WorldState(2.0, ()), 60)
    assert int(after[v, u].mean()) > int(before[v, u].mean()) + 60
    assert int(renderer.background(0)[v, u].mean()) == pytest.approx(int(before[v, u].mean()), abs=2)
    assert int(renderer.background(60)[v, u].mean()) == pytest.approx(int(after[v, u].mean()), abs=2)


def test_eight_rovers_carry_the_eight_hue_palette():
    looks = fleet_looks(8)
    assert [look.rover_id for look in looks] == [name for name, _ in EIGHT_HUES]
    hues = []
    for look in looks:
        b, g, r = look.marker_bgr
        hues.append(math.degrees(math.atan2(math.sqrt(3) * (g - b), 2 * r - g - b)) % 360)
    gaps = np.diff([*sorted(hues), sorted(hues)[0] + 360])
    assert gaps.min() > 20.0


@pytest.mark.slow
def test_grey_world_white_balance_drifts_as_a_warm_sunlit_patch_grows():
    setup = build("daylight", seed=0)
    renderer = setup.renderer()
    gains = np.array([renderer._sensor.white_balance(i) for i in range(0, 300, 10)])
    assert gains[:, 1] == pytest.approx(1.0)
    assert np.ptp(gains[:, 0]) > 0.01  # the blue gain follows the clouds over the patch
    frame = renderer.render(setup.world().state_at(1.0), 30)
    assert cv2.mean(frame)[0] > 0  # renders with it


def _step(width: int = 32) -> np.ndarray:
    """A green marker on the left half, a grey floor on the right (an edge across the columns)."""
    image = np.zeros((width, width, 3), np.uint8)
    image[:, : width // 2] = (40, 180, 60)
    image[:, width // 2 :] = (150, 150, 150)
    return image


@pytest.mark.parametrize("method", DEMOSAIC)
@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_demosaicing_gives_a_uniform_colour_back_and_puts_colour_fringes_on_an_edge(method, phase):
    flat = np.full((16, 16, 3), (40, 180, 60), np.uint8)
    assert np.abs(demosaic(flat, 2.2, method, phase).astype(int) - flat).max() <= 1
    image = _step()
    out = demosaic(image, 2.2, method, phase).astype(int)
    assert np.abs(out[4:-4, :12] - image[4:-4, :12]).max() <= 1  # away from the edge: as it was
    assert np.abs(out[4:-4, 12:20] - image[4:-4, 12:20]).max() > 20  # at the edge: colours interpolated across it


def test_sharpening_overshoots_an_edge_on_both_sides_and_leaves_the_chroma_alone():
    image = _step()
    out = sharpen_luma(image, 1.0, 1.0)
    luma_in = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(int)[16]
    luma_out = cv2.cvtColor(out, cv2.COLOR_BGR2GRAY).astype(int)[16]
    assert luma_out[15] < luma_in[15] - 5 and luma_out[16] > luma_in[16] + 5  # a dark and a bright halo
    assert np.array_equal(luma_out[:10], luma_in[:10]) and np.array_equal(luma_out[-10:], luma_in[-10:])
    chroma = out[16, 14].astype(int) - luma_out[14]
    assert np.abs(chroma - (image[16, 14].astype(int) - luma_in[14])).max() <= 1  # the same added to B, G and R
    assert np.array_equal(sharpen_luma(image, 0.0, 1.0), image)


def test_the_family_draws_every_processor_from_its_own_stream_of_the_seed():
    drawn = [draw_processing(np.random.default_rng(s)) for s in range(40)]
    assert {p.demosaic for p in drawn} == set(DEMOSAIC) and {p.bayer_phase for p in drawn} == set(BAYER_PHASES)
    assert all(0.0 <= p.sharpen <= 1.5 and 0.6 <= p.sharpen_sigma_px <= 1.4 for p in drawn)
    assert max(p.sharpen for p in drawn) > 1.0 and min(p.sharpen for p in drawn) < 0.3
    setup = build("lab", seed=4, camera="family")
    processing = setup.effects.processing
    assert processing is not None and str(processing.demosaic) in setup.camera_name
    # the rest of the seed's camera is what it drew before the processor joined the family
    before = draw_camera(scenario_rng("lab/camera", 4))
    assert before.processing is None and setup.camera_name.startswith(before.name + " ")
    with pytest.raises(SimulationError, match="demosaic"):
        SignalProcessing("nearest")
    with pytest.raises(SimulationError, match="sharpen"):
        SignalProcessing(sharpen=-1.0)


@pytest.mark.slow
def test_a_camera_with_a_processor_renders_a_grey_floor_grey():
    plain = _render(clean_effects())
    processed = _render(
        Effects(**{**clean_effects().__dict__, "processing": SignalProcessing("edge-aware", (1, 0), 1.2)})
    )
    centre = (slice(300, 420), slice(560, 720))
    assert np.abs(plain[centre].astype(int) - processed[centre].astype(int)).max() <= 2
