"""The renderer: markers where the camera model puts them, and camera/scene effects that behave like physics."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from edge.camera import paper_camera
from edge.sim.effects import (
    AutoExposure,
    Effects,
    Exposure,
    Flicker,
    Occluder,
    SensorNoise,
)
from edge.sim.raster import polygon_centroid
from edge.sim.render import Renderer
from edge.sim.scenarios import build, lens_camera
from edge.sim.scene import RoverLook, Scene, fleet_looks, marker_albedo_for_hue
from edge.sim.sensor import auto_exposure_gains, flicker_amplitude, noise_sigma_lut
from edge.sim.world import RoverState, WorldState
from tests.support.sim import black_scene, clean_effects, linear

POSES = [  # (x, y, heading deg): near, middle and far side, corners, all headings
    (20.0, 15.0, 0.0),
    (195.75, 10.0, 30.0),
    (380.0, 20.0, 90.0),
    (100.0, 275.0, 135.0),
    (300.0, 300.0, 200.0),
    (15.0, 540.0, 90.0),
    (195.75, 549.5, 0.0),
    (385.0, 535.0, 300.0),
    (250.0, 450.0, 71.3),
]


def _still(x: float, y: float, heading_deg: float, rover_id: str = "red") -> RoverState:
    return RoverState(rover_id, x, y, math.radians(heading_deg), 0.0, 0.0)


@pytest.fixture(scope="module", params=[("paper", None), ("lens", None), ("paper", 0.7), ("lens", 0.7)])
def black_renderer(request):
    """Sharp (box-filtered pixels only) and with the lens's point spread, through both cameras."""
    which, psf = request.param
    camera = paper_camera() if which == "paper" else lens_camera()
    return Renderer(camera, black_scene(fleet_looks(1)), clean_effects(psf_sigma_px=psf))


@pytest.mark.slow
@pytest.mark.parametrize("pose", POSES)
def test_marker_is_drawn_where_the_camera_model_projects_it(black_renderer, pose):
    """Intensity-weighted centroid (linear light) of the rendered marker vs the area centroid of its projected
    outline: within 0.05 px (the geometry is exact area coverage; the residue is the pixel grid's box filter; the
    lens's symmetric point spread moves no centroid)."""
    rover = _still(*pose)
    image = black_renderer.render(WorldState(0.0, (rover,)), 0)
    weight = linear(image)[..., 2]  # the red marker's own channel; floor and body are black
    rows, cols = np.nonzero(weight > 0)
    assert rows.size > 0
    w = weight[rows, cols]
    measured = np.array([np.sum(w * cols), np.sum(w * rows)]) / np.sum(w)
    expected = polygon_centroid(black_renderer.marker_outline_px(rover))
    assert np.hypot(*(measured - expected)) < 0.05


@pytest.mark.slow
def test_far_marker_is_about_20_by_9_px(black_renderer):
    rover = _still(195.75, 549.5, 90.0)
    image = black_renderer.render(WorldState(0.0, (rover,)), 0)
    rows, cols = np.nonzero(linear(image)[..., 2] > 0.25 * linear(image)[..., 2].max())
    assert 18 <= cols.max() - cols.min() + 1 <= 24
    assert 8 <= rows.max() - rows.min() + 1 <= 12


@pytest.mark.slow
@pytest.mark.parametrize(("x", "y", "min_px"), [(195.75, 5.0, 0.5), (195.75, 540.0, 0.05)])
def test_area_centroid_is_not_the_projected_centre_but_maps_back_to_it(x, y, min_px):
    """Perspective: the pixel area centroid of a marker is not the projection of its centre (most visibly on the
    near side, where the marker spans the widest angle), while the outline mapped back to the marker plane has its
    area centroid exactly at the centre."""
    camera = paper_camera()
    renderer = Renderer(camera, black_scene(fleet_looks(1)), clean_effects())
    rover = _still(x, y, 90.0)
    outline = renderer.marker_outline_px(rover)
    centre_px = camera.project(np.array([[rover.x_cm, rover.y_cm, 13.0]]))[0]
    assert np.hypot(*(polygon_centroid(outline) - centre_px)) > min_px
    on_plane = camera.pixel_to_plane(outline, 13.0)
    assert polygon_centroid(on_plane) == pytest.approx([rover.x_cm, rover.y_cm], abs=1e-6)


@pytest.mark.slow
def test_same_seed_same_frames_other_seed_other_noise():
    setup = build("lab", seed=3)
    world = setup.world()
    state = world.state_at(2.0)
    a = setup.renderer().render(state, 60)
    b = setup.renderer().render(state, 60)
    np.testing.assert_array_equal(a, b)
    other = build("lab", seed=4)
    c = other.renderer().render(state, 60)
    assert np.mean(np.abs(a.astype(int) - c.astype(int))) > 1.0


def test_background_is_a_separate_capture_of_the_empty_scene():
    setup = build("lab", seed=0)
    renderer = setup.renderer()
    empty = renderer.background(0)
    frame = renderer.render(setup.world().state_at(0.0), 0)
    diff = np.abs(empty.astype(int) - frame.astype(int))
    assert 0.5 < diff.mean() < 10.0  # other noise everywhere, rovers only in a few windows
    assert np.median(diff) < 6


def test_visibility_counts_what_is_in_view_and_not_hidden():
    camera = paper_camera()
    looks = fleet_looks(3)
    person = Occluder(keyframes=((0.0, 195.0, 150.0), (10.0, 195.0, 150.0)))
    effects = Effects(auto_exposure=None, noise=None, motion_blur=False, occluders=(person,))
    renderer = Renderer(camera, Scene(looks), effects)
    state = WorldState(
        0.0,
        (
            _still(60.0, 60.0, 0.0, "red"),  # in plain view
            _still(195.0, 420.0, 90.0, "green"),  # behind the person standing at y = 150
            _still(380.0, -120.0, 0.0, "blue"),  # beyond the near edge of the view
        ),
    )
    renderer.render(state, 0)
    assert renderer.visibility["red"] == pytest.approx(1.0, abs=1e-6)
    assert renderer.visibility["green"] < 0.05
    assert renderer.visibility["blue"] == 0.0


def test_rovers_of_equal_height_never_hide_each_others_markers():
    # Seen from 280 cm up, a body 13 cm tall in front of another cannot reach above the other's top: the marker
    # plane is the highest thing a rover has, so only taller things (people) hide markers.
    renderer = Renderer(paper_camera(), Scene(fleet_looks(2)), Effects(noise=None, auto_exposure=None))
    far = _still(195.0, 528.0, 0.0, "green")
    near = _still(195.0, 506.0, 0.0, "red")  # bodies 2 cm apart
    image = renderer.render(WorldState(0.0, (far, near)), 0)
    assert renderer.visibility["red"] == pytest.approx(1.0, abs=1e-6)
    assert renderer.visibility["green"] == pytest.approx(1.0, abs=1e-6)
    assert image.shape == (720, 1280, 3)


def test_marker_colours_are_saturated_but_not_pure_primaries():
    renderer = build("lab").renderer()
    red, green, blue = (renderer.nominal_marker_bgr(i) for i in ("red", "green", "blue"))
    assert red[2] > 2 * max(red[:2]) and min(red) > 20
    assert green[1] > 1.4 * max(green[0], green[2]) and min(green) > 20
    assert blue[0] > 1.4 * max(blue[1:]) and min(blue) > 20


def test_crowd_hues_are_distinct():
    hues = []
    for look in fleet_looks(12):
        b, g, r = look.marker_bgr
        hues.append(math.degrees(math.atan2(math.sqrt(3) * (g - b), 2 * r - g - b)) % 360)
    gaps = np.diff(sorted(hues))
    assert len(set(look.rover_id for look in fleet_looks(12))) == 12
    assert gaps.min() > 15.0
    assert marker_albedo_for_hue(0.0) != marker_albedo_for_hue(30.0)


# -- camera effects ---------------------------------------------------------------------------------------------
def test_shot_noise_grows_with_the_signal_in_linear_light():
    noise = SensorNoise()
    lut = noise_sigma_lut(noise, gain=1.0, gamma=2.2)[0].astype(float) / 16.0
    values = np.arange(256)
    lin = (values / 255.0) ** 2.2
    slope = 255.0 / 2.2 * np.maximum(lin, 1e-12) ** (1 / 2.2 - 1)
    sigma_lin = lut / slope
    samples = sigma_lin[[40, 80, 120, 160, 200, 240]]
    assert np.all(np.diff(samples) > 0)  # more light, more (absolute) noise
    assert samples[-1] > 3 * samples[0]
    assert lut[255] == 0  # saturated pixels carry no noise
    brighter = noise_sigma_lut(noise, gain=2.0, gamma=2.2)[0]
    assert np.all(brighter[40:] >= lut[40:] * 16 - 1)  # analogue gain amplifies noise


def test_rendered_noise_is_stronger_in_linear_light_on_bright_floor_than_on_dark_bodies():
    setup = build("lab", seed=1)
    renderer = setup.renderer()
    state = setup.world().state_at(0.0)
    a = linear(renderer.render(state, 10))
    b = linear(renderer.render(state, 11))
    diff = (a - b)[..., 1]
    ref = a[..., 1]
    bright = diff[ref > 0.3].std()
    dark = diff[(ref > 0.005) & (ref < 0.03)].std()
    assert bright > 2 * dark


@pytest.mark.parametrize(
    ("exposure_s", "expected"), [(1 / 100, 0.0), (1 / 50, 0.0), (1 / 250, 0.2 * 0.7568), (1 / 60, 0.2 * 0.1654)]
)
def test_flicker_band_amplitude_follows_the_exposure_time(exposure_s, expected):
    assert flicker_amplitude(Flicker(modulation=0.2), exposure_s) == pytest.approx(expected, abs=2e-3)


@pytest.mark.slow
def test_rolling_flicker_makes_bands_that_roll():
    camera = paper_camera()
    scene = Scene(fleet_looks(1))
    effects = Effects(
        exposure=Exposure(exposure_s=1 / 250),
        auto_exposure=None,
        noise=None,
        vignetting=None,
        flicker=Flicker(modulation=0.25),
    )
    flat = Renderer(
        camera, scene, Effects(exposure=Exposure(exposure_s=1 / 250), auto_exposure=None, noise=None, vignetting=None)
    )
    banded = Renderer(camera, scene, effects)
    empty = WorldState(0.0, ())
    ratio0 = linear(banded.render(empty, 0)).mean(axis=(1, 2)) / linear(flat.render(empty, 0)).mean(axis=(1, 2))
    ratio1 = linear(banded.render(empty, 1)).mean(axis=(1, 2)) / linear(flat.render(empty, 1)).mean(axis=(1, 2))
    rows = np.arange(720)
    centred = ratio0 - ratio0.mean()
    periods = np.arange(150.0, 300.0, 0.5)
    power = [abs(np.sum(centred * np.exp(2j * np.pi * rows / p))) for p in periods]
    period_rows = periods[int(np.argmax(power))]
    assert period_rows == pytest.approx(225.0, rel=0.06)  # 10 ms ripple / 44.4 us per row
    assert ratio0.max() - ratio0.min() == pytest.approx(2 * 0.25 * 0.7568, rel=0.15)
    assert np.abs(ratio0 - ratio1).max() > 0.05  # the bands move between frames


def test_auto_exposure_lags_a_step_in_the_light():
    levels = np.r_[np.ones(30), np.full(60, 0.6)]
    gains = auto_exposure_gains(levels, AutoExposure(rate=0.25, delay_frames=2))
    seen = levels * gains
    assert seen[29] == pytest.approx(1.0)
    assert seen[31] < 0.7  # under-exposed right after the lights dim
    assert abs(seen[-1] - 1.0) < 0.01  # and recovered a second later
    recovered = np.argmax(np.abs(seen[30:] - 1.0) < 0.05)
    assert 5 <= recovered <= 20


@pytest.mark.slow
def test_motion_blur_smears_along_the_motion_and_keeps_the_centroid():
    camera = paper_camera()
    scene = black_scene(fleet_looks(1))
    sharp = Renderer(camera, scene, clean_effects())
    blurred = Renderer(
        camera,
        scene,
        Effects(
            exposure=Exposure(exposure_s=1 / 30),
            auto_exposure=None,
            noise=None,
            vignetting=None,
            optics=None,
            motion_blur=True,
        ),
    )
    rover = RoverState("red", 150.0, 60.0, 0.0, 30.0, 0.0)  # 30 cm/s along x, 1 cm during a 1/30 s exposure
    still = RoverState("red", 150.0, 60.0, 0.0, 0.0, 0.0)
    a = linear(sharp.render(WorldState(0.0, (still,)), 0))[..., 2]
    b = linear(blurred.render(WorldState(0.0, (rover,)), 0))[..., 2]

    def spread_and_centroid(w):
        rows, cols = np.nonzero(w > 0)
        weights = w[rows, cols]
        c = np.array([np.sum(weights * cols), np.sum(weights * rows)]) / weights.sum()
        return np.sum(weights * (cols - c[0]) ** 2) / weights.sum(), c

    (var_a, ca), (var_b, cb) = spread_and_centroid(a), spread_and_centroid(b)
    px_per_cm = np.linalg.norm(np.diff(camera.project(np.array([[150.0, 60.0, 13.0], [151.0, 60.0, 13.0]])), axis=0))
    # a box blur of length L adds L^2 / 12 to the variance along the motion
    assert math.sqrt(12.0 * (var_b - var_a)) == pytest.approx(px_per_cm * 1.0, rel=0.1)
    assert np.hypot(*(ca - cb)) < 0.05


# -- scene effects ----------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_glare_clips_to_white_and_sunlight_is_warmer_than_lamplight():
    setup = build("sun", seed=0)
    renderer = setup.renderer()
    image = renderer.background(0)
    glare = setup.effects.glare
    assert glare is not None
    u, v = (round(c) for c in setup.camera.project(np.array([[glare.x_cm, glare.y_cm, 0.0]]))[0])
    core = image[v - 2 : v + 3, u - 2 : u + 3].reshape(-1, 3)
    assert core.min() >= 250  # saturated in every channel: bright and desaturated
    sun = setup.effects.sun
    assert sun is not None
    patch = sun.patch_cm(0.0)
    inside = setup.camera.project(np.array([[patch[:, 0].mean() - 40.0, patch[:, 1].mean(), 0.0]]))[0]
    outside = setup.camera.project(np.array([[330.0, 200.0, 0.0]]))[0]
    lit = image[int(inside[1]) - 3 : int(inside[1]) + 4, int(inside[0]) - 3 : int(inside[0]) + 4].reshape(-1, 3).mean(0)
    lamp = (
        image[int(outside[1]) - 3 : int(outside[1]) + 4, int(outside[0]) - 3 : int(outside[0]) + 4]
        .reshape(-1, 3)
        .mean(0)
    )
    assert lit.mean() > lamp.mean() * 1.2
    assert lit[2] / lit[0] > lamp[2] / lamp[0] * 1.05  # more red than blue: a lower colour temperature


@pytest.mark.slow
def test_passing_clouds_change_the_suns_colour_temperature():
    setup = build("sun", seed=0)
    renderer = setup.renderer()
    sun = setup.effects.sun
    assert sun is not None
    patch = sun.patch_cm(0.0)
    centre = setup.camera.project(np.array([[patch[:, 0].mean() - 40.0, patch[:, 1].mean(), 0.0]]))[0]
    u, v = int(centre[0]), int(centre[1])
    ratios = []
    for i in range(0, int(sun.cloud_period_s * 30), 15):
        px = renderer.background(i)[v - 3 : v + 4, u - 3 : u + 4].reshape(-1, 3).astype(float).mean(0)
        ratios.append(px[2] / px[0])
    assert max(ratios) - min(ratios) > 0.05


def test_person_hides_what_is_behind_and_leaves():
    setup = build("occlusion", seed=0)
    person = setup.effects.occluders[0]
    t_stand = person.keyframes[1][0] + 0.5
    renderer = setup.renderer()
    empty = WorldState(0.0, ())
    with_person = renderer.render(empty, int(t_stand * 30))
    before = renderer.render(empty, 0)
    x, y = person.keyframes[1][1:]
    torso = setup.camera.project(np.array([[x, y, 120.0]]))[0]
    u, v = int(torso[0]), int(torso[1])
    assert (
        np.abs(with_person[v - 3 : v + 4, u - 3 : u + 4].astype(int) - before[v - 3 : v + 4, u - 3 : u + 4]).mean() > 20
    )


def test_body_sides_and_shadow_are_drawn_around_the_marker():
    camera = paper_camera()
    renderer = Renderer(camera, Scene(fleet_looks(1)), Effects(noise=None, auto_exposure=None))
    empty = renderer.render(WorldState(0.0, ()), 0).astype(int)
    rover = _still(150.0, 60.0, 0.0)
    image = renderer.render(WorldState(0.0, (rover,)), 0).astype(int)
    side = camera.project(np.array([[150.0, 60.0 - 10.0, 6.0]]))[0]  # the side facing the camera
    halo = camera.project(np.array([[150.0, 60.0 - 12.5, 0.0]]))[0]  # floor just beside the body
    su, sv = round(side[0]), round(side[1])
    hu, hv = round(halo[0]), round(halo[1])
    assert image[sv, su].mean() < 0.4 * empty[sv, su].mean()  # dark body side
    assert 0.5 * empty[hv, hu].mean() < image[hv, hu].mean() < 0.97 * empty[hv, hu].mean()  # soft shadow


def test_unknown_rover_is_a_clear_error():
    from edge.errors import SimulationError

    renderer = Renderer(paper_camera(), Scene((RoverLook("red", (0.1, 0.1, 0.6)),)), Effects(noise=None))
    with pytest.raises(SimulationError, match="'ghost' is not in the scene"):
        renderer.render(WorldState(0.0, (_still(10.0, 10.0, 0.0, "ghost"),)), 0)


# -- heading markers --------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("heading_deg", [0.0, 75.0, 200.0])
def test_aruco_tag_is_readable_near_the_camera_and_points_to_the_front(heading_deg):
    looks = fleet_looks(1, heading="aruco")
    renderer = Renderer(paper_camera(), Scene(looks), Effects(auto_exposure=None))
    rover = _still(150.0, 40.0, heading_deg)
    image = renderer.render(WorldState(0.0, (rover,)), 0)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = detector.detectMarkers(image)
    assert ids is not None and ids.ravel().tolist() == [0]
    c = corners[0].reshape(4, 2)
    tag_up = 0.5 * (c[0] + c[1]) - c.mean(axis=0)  # the tag's top edge faces the rover's front
    th = math.radians(heading_deg)
    ends = paper_camera().project(np.array([[150.0, 40.0, 13.0], [150.0 + math.cos(th), 40.0 + math.sin(th), 13.0]]))
    front = ends[1] - ends[0]
    cos = np.dot(tag_up, front) / np.linalg.norm(tag_up) / np.linalg.norm(front)
    assert cos > math.cos(math.radians(20))


def test_two_tone_marker_has_a_pale_front():
    looks = fleet_looks(1, heading="two_tone")
    renderer = Renderer(paper_camera(), Scene(looks), Effects(auto_exposure=None, noise=None))
    rover = _still(150.0, 60.0, 0.0)
    image = renderer.render(WorldState(0.0, (rover,)), 0).astype(int)
    front, back = paper_camera().project(np.array([[150.0 + 8.5, 60.0, 13.0], [150.0 - 5.0, 60.0, 13.0]]))
    f = image[round(front[1]), round(front[0])]
    b = image[round(back[1]), round(back[0])]
    assert min(f) > 150 and max(f) - min(f) < 40  # near-white paper
    assert b[2] > 2 * max(b[0], b[1])  # red


def test_heading_option_applies_to_every_rover_of_a_scenario():
    setup = build("crowd", rovers=5, heading="aruco")
    assert [look.heading for look in setup.scene.rovers] == ["aruco"] * 5
    assert [look.aruco_id for look in setup.scene.rovers] == [0, 1, 2, 3, 4]
