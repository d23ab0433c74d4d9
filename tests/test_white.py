"""Colour relative to the local light (edge.white): markers keep their hue under a warm patch, under an automatic
white balance and with the lamps off; grey and white things never become markers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.camera import paper_camera
from edge.segmentation import LINEAR, chroma_of_bgr, linear_bgr
from edge.sim.effects import Effects, Prop, SunPatch
from edge.sim.render import Renderer
from edge.sim.scene import BLUE_BGR, RoverLook, Scene
from edge.sim.world import RoverState, WorldState
from edge.white import LocalWhite, encode_linear
from tests.conftest import benchmark_module

WARM_SUN = SunPatch(strength=2.0, clear_bgr=(0.4, 0.72, 1.0), cloud_depth=0.0)


def _hue_deg(bgr) -> float:
    c1, c2, _ = chroma_of_bgr(bgr)
    return math.degrees(math.atan2(c2, c1))


def _saturation(bgr) -> float:
    c1, c2, lum = chroma_of_bgr(bgr)
    return math.hypot(c1, c2) / max(lum, 1.0)


def _box(uv: np.ndarray, half: int = 40) -> tuple[int, int, int, int]:
    u, v = round(uv[0]), round(uv[1])
    return u - half, v - half, u + half, v + half


@pytest.mark.slow
def test_a_blue_marker_in_a_warm_sunlit_patch_shows_its_own_colour_again():
    """Under a patch 3 times brighter and much warmer than the lamps the blue marker loses a third of its
    saturation; judged against the light there, it has the colour it was enrolled with."""
    effects = Effects(auto_exposure=None, noise=None, motion_blur=False, sun=WARM_SUN)
    patch = WARM_SUN.patch_cm(13.0)
    x, y = float(patch[:, 0].mean()), float(patch[:, 1].mean())
    look = RoverLook("blue", BLUE_BGR)
    renderer = Renderer(paper_camera(), Scene((look,)), effects)
    configured = renderer.nominal_marker_bgr("blue")  # under the lamps, as enrolled
    image = renderer.render(WorldState(0.0, (RoverState("blue", x, y, 0.3, 0.0, 0.0, 0.0),)), 0)
    background = renderer.background(0)
    uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
    u, v = round(uv[0]), round(uv[1])
    seen = image[v - 2 : v + 3, u - 3 : u + 4].reshape(-1, 3).mean(axis=0)
    assert _saturation(seen) < 0.8 * _saturation(configured)

    white = LocalWhite(background, np.ones(background.shape[:2], bool))
    box = _box(uv)
    x0, y0, x1, y1 = box
    crop, ref = image[y0:y1, x0:x1], background[y0:y1, x0:x1]
    corrected = white.correct(crop, white.gains(box, crop, ref, np.ones(crop.shape[:2], bool)))
    c = corrected[40 - 2 : 40 + 3, 40 - 3 : 40 + 4].reshape(-1, 3).mean(axis=0)
    assert abs(math.degrees(math.remainder(math.radians(_hue_deg(c) - _hue_deg(configured)), math.tau))) < 4.0
    assert _saturation(c) == pytest.approx(_saturation(configured), rel=0.1)


@pytest.mark.slow
def test_a_grey_box_in_the_sun_stays_grey_and_a_white_one_white():
    boxes = (
        Prop(150.0, 300.0, (30.0, 30.0, 25.0), 0.0, (0.5, 0.5, 0.5)),
        Prop(240.0, 250.0, (30.0, 30.0, 25.0), 0.0, (0.85, 0.85, 0.85)),
    )
    effects = Effects(auto_exposure=None, noise=None, motion_blur=False, sun=WARM_SUN, props=boxes)
    renderer = Renderer(paper_camera(), Scene(()), effects)
    image = renderer.render(WorldState(0.0, ()), 0)
    background = Renderer(paper_camera(), Scene(()), Effects(**{**effects.__dict__, "props": ()})).background(0)
    white = LocalWhite(background, np.ones(background.shape[:2], bool))
    for prop in boxes:
        uv = paper_camera().project(np.array([[prop.x_cm, prop.y_cm, prop.size_cm[2]]]))[0]
        box = _box(uv, 30)
        x0, y0, x1, y1 = box
        crop = image[y0:y1, x0:x1]
        raw_top = crop[27:34, 27:34].reshape(-1, 3).mean(axis=0)
        fixed = white.correct(crop, white.gains(box, crop, background[y0:y1, x0:x1], np.ones(crop.shape[:2], bool)))
        top = fixed[27:34, 27:34].reshape(-1, 3).mean(axis=0)
        if max(raw_top) < 250:  # the grey one (the white one is clipped white in the sun)
            assert _saturation(raw_top) > 0.12  # the warm light tints it
        assert _saturation(top) < 0.08  # relative to the light there: grey (markers have 0.3-0.7; near-clipped 0.06)


def test_the_border_of_a_window_follows_the_white_balance_between_refreshes():
    reference = np.full((120, 160, 3), 128, np.uint8)
    white = LocalWhite(reference, np.ones((120, 160), bool))
    tint = np.array([1.25, 1.0, 0.8], np.float32)  # the camera's white balance moved: bluer
    frame = encode_linear(np.clip(linear_bgr(reference) * tint, 0, 1))
    box = (40, 30, 120, 90)
    crop = frame[30:90, 40:120]
    gains = white.gains(box, crop, reference[30:90, 40:120], np.ones((60, 80), bool))
    expected = (1.0 / tint) / (1.0 / tint).mean()
    assert gains == pytest.approx(expected, rel=0.02)
    grey_again = white.correct(crop, gains)[30, 40]
    assert _saturation(grey_again) < 0.01


def test_linear_encoding_round_trips_every_value():
    values = np.arange(256, dtype=np.uint8).reshape(1, -1, 1).repeat(3, axis=2)
    assert np.array_equal(encode_linear(LINEAR[values]), values)


@pytest.mark.slow
@pytest.mark.parametrize("camera", ["nominal", "family"])
def test_rovers_in_the_daylight_scenario_are_all_tracked_and_the_boxes_never_taken_for_one(camera):
    """The sunlit patch, its glare, half the lamps off and an automatic white balance: every marker in view gets a
    pose within 2 cm, nothing else does (the grey and white boxes are put down at 2 and 3 s)."""
    runs = benchmark_module("tracking_runs")
    render_clip, run_clip, summary = runs.render_clip, runs.run_clip, runs.summary

    clip = render_clip("daylight", 3, frames=240, camera=camera)
    score = run_clip(clip, "particles")
    for rid, s in score.rovers.items():
        row = summary(s)
        assert row["det"] >= 0.99, rid
        assert row["ghosts"] == 0 and row["swaps"] == 0, rid
        assert row["max"] < 2.0, rid


def test_a_poster_of_a_markers_colour_on_the_floor_is_not_taken_for_the_light():
    """The reference's colour is the light's only where no light could have that colour: a red poster lying on the
    floor leaves a window over it seen under the room's white, not corrected towards cyan."""
    floor = np.full((256, 320, 3), 150, np.uint8)
    poster = floor.copy()
    poster[64:192, 96:224] = (50, 45, 190)  # four blocks of red paper
    valid = np.ones(floor.shape[:2], bool)
    box = (112, 80, 208, 176)
    plain = LocalWhite(floor, valid).gains(box, floor[80:176, 112:208], floor[80:176, 112:208], valid[80:176, 112:208])
    with_poster = LocalWhite(poster, valid).gains(
        box, poster[80:176, 112:208], poster[80:176, 112:208], valid[80:176, 112:208]
    )
    assert np.allclose(with_poster, plain, atol=0.02)


def test_the_lights_map_follows_the_reference_band_by_band():
    """The background reference renews a band of rows per frame; each row of 32-pixel blocks of the light's map is
    recomputed once the band has passed all of it, and after a whole cycle the map is the one computed at once."""
    floor = np.full((160, 256, 3), 150, np.uint8)
    valid = np.ones(floor.shape[:2], bool)
    warm = floor.copy()
    warm[64:128] = (130, 150, 172)  # a warm patch over block rows 2 and 3 (rows 64-127)
    white = LocalWhite(floor, valid)
    before = white.coarse.copy()
    white.update(warm, valid, slice(0, 70))  # block rows 0 and 1 (ending at rows 32 and 64) complete
    assert np.array_equal(white.coarse[2:], before[2:])
    white.update(warm, valid, slice(70, 100))  # block row 2 (ending at row 96) complete
    assert not np.allclose(white.coarse[2], before[2]) and np.array_equal(white.coarse[3], before[3])
    for start in range(100, 160, 30):
        white.update(warm, valid, slice(start, start + 30))
    at_once = LocalWhite(floor, valid)
    at_once.update(warm, valid)
    assert np.array_equal(white.coarse, at_once.coarse)


def _crowded_border() -> tuple[LocalWhite, np.ndarray, np.ndarray, tuple[int, int, int, int], list]:
    """A window (80 x 60) whose border is more than half covered by two other rovers: black bodies with a blue
    marker on one, over an empty grey floor in the reference."""
    reference = np.full((120, 160, 3), 170, np.uint8)
    frame = reference.copy()
    frame[20:70, 30:90] = (15, 15, 15)  # a black body over the window's top left
    frame[30:55, 40:75] = (190, 90, 40)  # its blue marker
    frame[55:100, 80:135] = (15, 15, 15)  # another body over its right and bottom
    box = (40, 30, 120, 90)
    others = [(30, 20, 90, 70), (80, 55, 135, 100)]
    return LocalWhite(reference, np.ones((120, 160), bool)), frame, reference, box, others


def test_other_rovers_on_a_windows_border_are_not_taken_for_the_light():
    """Three rovers in a row (the lens scenario's diagonal runs) each covered more than half of the next one's
    border: the median read black bodies and a blue marker as the light, and a red marker shown under a red gain of
    1.65 grew by a third; its learned area then refused the marker for the rest of the clip."""
    white, frame, reference, box, others = _crowded_border()
    x0, y0, x1, y1 = box
    valid = np.ones((y1 - y0, x1 - x0), bool)
    gains = white.gains(box, frame[y0:y1, x0:x1], reference[y0:y1, x0:x1], valid, others)
    assert gains == pytest.approx(np.ones(3), abs=0.02)


def test_a_border_whose_colour_no_light_has_falls_back_to_the_lights_map():
    """Without the other rovers' boxes (a rover not tracked yet), a border ratio whose colour is farther from the
    room's white than any lamp or daylight is something lying there, not the light: the map's light is used."""
    white, frame, reference, box, _ = _crowded_border()
    x0, y0, x1, y1 = box
    frame = frame.copy()
    frame[y0 : y0 + 2, x0:x1] = (200, 60, 30)  # a blue thing along the whole top border, more besides
    frame[y0:y1, x0 : x0 + 2] = (200, 60, 30)
    frame[y1 - 2 : y1, x0:x1] = (200, 60, 30)
    valid = np.ones((y1 - y0, x1 - x0), bool)
    gains = white.gains(box, frame[y0:y1, x0:x1], reference[y0:y1, x0:x1], valid)
    assert gains == pytest.approx(np.ones(3), abs=0.02)


WOOD_BGR = (60, 110, 170)  # a warm wooden floor (8-bit B, G, R)


def _body_on_wood(body_tint: tuple[float, float, float], level: float) -> np.ndarray:
    """A dark body's colour over the wood: the wood's linear colour times ``level`` and ``body_tint``."""
    wood = linear_bgr(np.array([[WOOD_BGR]], np.uint8))[0, 0]
    return encode_linear(np.asarray(wood * level * np.array(body_tint), np.float32)[None, None])[0, 0]


def test_a_rovers_own_black_body_on_most_of_its_windows_border_is_not_taken_for_the_light():
    """The cross clip's green rover (seed 14641, wood, a black body) was lost for a second: the body held most of
    its window's border, and its ratio to the wood (a twelfth of its brightness, relatively bluer) read as a blue
    light that moved the teal marker out of its hue. Border pixels whose brightness changed far more than the whole
    view's did are not floor."""
    reference = np.full((120, 160, 3), WOOD_BGR, np.uint8)
    white = LocalWhite(reference, np.ones((120, 160), bool))
    frame = reference.copy()
    box = (40, 30, 120, 90)
    frame[34:90, 40:120] = _body_on_wood((1.35, 0.92, 0.73), 0.08)  # three of the border's four sides
    white.observe(frame, reference, np.ones((120, 160), bool))
    crop, ref = frame[30:90, 40:120], reference[30:90, 40:120]
    valid = np.ones((60, 80), bool)

    border = (linear_bgr(crop) + 1e-4) / (linear_bgr(ref) + 1e-4)
    ring = np.ones((60, 80), bool)
    ring[2:-2, 2:-2] = False
    plain = np.median(border[ring], axis=0)
    assert plain[0] / plain[2] > 1.5  # the border's plain median: a blue light
    assert white.gains(box, crop, ref, valid) == pytest.approx(np.ones(3), abs=0.03)


def test_the_whole_views_change_is_the_light_where_a_windows_border_shows_no_floor():
    """A window with no floor on its border (the reference not known there, or all of it a body) takes the light
    map's colour changed as the whole view's has: the white balance moved everywhere at once."""
    reference = np.full((120, 160, 3), 128, np.uint8)
    white = LocalWhite(reference, np.ones((120, 160), bool))
    tint = np.array([1.25, 1.0, 0.8], np.float32)
    frame = encode_linear(np.clip(linear_bgr(reference) * tint, 0, 1))
    box = (40, 30, 120, 90)
    unknown = np.zeros((60, 80), bool)
    assert white.gains(box, frame[30:90, 40:120], reference[30:90, 40:120], unknown) == pytest.approx(np.ones(3))
    white.observe(frame, reference, np.ones((120, 160), bool))
    gains = white.gains(box, frame[30:90, 40:120], reference[30:90, 40:120], unknown)
    expected = (1.0 / tint) / (1.0 / tint).mean()
    assert gains == pytest.approx(expected, rel=0.02)


def test_the_acquisitions_whole_frame_gains_follow_the_views_white_balance():
    """The acquisition pass looks for a lost rover over the whole (downscaled) frame under the light map's gains:
    changed as the whole view has, the white balance of now, not of the reference's last refresh."""
    reference = np.full((120, 160, 3), 128, np.uint8)
    white = LocalWhite(reference, np.ones((120, 160), bool))
    tint = np.array([1.25, 1.0, 0.8], np.float32)
    assert white.frame_gains((30, 40)) == pytest.approx(np.ones((30, 40, 3)))
    white.observe(encode_linear(np.clip(linear_bgr(reference) * tint, 0, 1)), reference, np.ones((120, 160), bool))
    expected = (1.0 / tint) / (1.0 / tint).mean()
    assert white.frame_gains((30, 40)) == pytest.approx(np.broadcast_to(expected, (30, 40, 3)), rel=0.02)


def test_a_border_dimmed_with_the_whole_view_is_still_floor():
    """The lamps dimmed to a fifth over the whole view and a warmer light where the window is: its border changed
    as the view did, so it is floor and gives the light there."""
    reference = np.full((120, 160, 3), 128, np.uint8)
    white = LocalWhite(reference, np.ones((120, 160), bool))
    frame = encode_linear(linear_bgr(reference) * np.float32(0.2))
    tint = np.array([0.8, 1.0, 1.25], np.float32)
    frame[30:90, 40:120] = encode_linear(linear_bgr(reference[30:90, 40:120]) * np.float32(0.2) * tint)
    box = (40, 30, 120, 90)
    white.observe(frame, reference, np.ones((120, 160), bool))
    assert white.level == pytest.approx(0.2, rel=0.05)
    gains = white.gains(box, frame[30:90, 40:120], reference[30:90, 40:120], np.ones((60, 80), bool))
    expected = (1.0 / tint) / (1.0 / tint).mean()
    assert gains == pytest.approx(expected, rel=0.03)


@pytest.mark.slow
def test_two_tone_rovers_driving_in_a_row_through_the_lens_scenario_are_all_tracked():
    """The lens scenario's three rovers in a diagonal row, two-tone: the red one was lost at frame 153 and never
    found again (37 % of its frames) once its neighbours had held its window's border."""
    runs = benchmark_module("tracking_runs")
    clip = runs.render_clip("lens", 0, frames=300, heading="two_tone")
    score = runs.run_clip(clip, "particles")
    for rid, s in score.rovers.items():
        row = runs.summary(s)
        assert row["det"] >= 0.99, (rid, row)
        assert row["max"] < 2.0, (rid, row)


def test_a_floors_own_tint_from_block_to_block_is_not_taken_for_the_light_and_a_sunlit_patch_is():
    """A wooden floor's planks differ in tint from one 32-pixel block to the next by as much as a sunlit patch's light
    differs from the lamps' (the family's wood: a block 0.02-0.05 warmer or cooler than the room's white), and block
    by block each tint was corrected as if it were the light. The light's map is the median of each block and its 8
    neighbours: a block's own tint is about halved, the light of a patch of 3 blocks or more is kept."""
    rng = np.random.default_rng(3)
    blocks = 1.0 + rng.uniform(-0.06, 0.06, (8, 10, 1)) * np.array([1.0, 0.0, -1.0])  # a tint per block
    floor = np.repeat(np.repeat(130.0 * blocks, 32, axis=0), 32, axis=1)
    floor[64:192, 96:224] *= (0.9, 1.3, 1.7)  # a sunlit patch over 4 x 4 blocks: brighter and warmer
    floor = np.clip(floor, 0, 255).astype(np.uint8)
    white = LocalWhite(floor, np.ones(floor.shape[:2], bool))
    outside = np.ones((8, 10), bool)
    outside[1:7, 2:8] = False  # the patch and the blocks beside it
    lamps = np.median(white.coarse[outside], axis=0)  # the lamps' light, the floor's tints about it
    tint = np.abs(white.coarse[outside] - lamps).max(axis=1)
    left = np.abs(white.light[outside] - lamps).max(axis=1)
    assert np.median(left) < 0.6 * np.median(tint)  # about halved
    sun = np.median(white.coarse[2:6, 3:7].reshape(-1, 3), axis=0)  # the patch's light, its planks' tints about it
    inside = white.light[3:5, 4:6].reshape(-1, 3)  # its central blocks
    assert np.abs(inside - sun).max() < 0.1 * np.abs(sun - lamps).max()
