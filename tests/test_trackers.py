"""The three window trackers and the geometry they share (perspective-correct, sub-pixel marker centres)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from edge.background import BackgroundModel
from edge.camera import MARKER_HEIGHT_CM
from edge.segmentation import ColorModel, dilate
from edge.tracker_config import TrackerConfig
from edge.trackers import METHODS, make_tracker
from edge.trackers.base import Measurement, NullClock, PlaneGrid, RoverModel, world_blob
from edge.trackers.refine import marker_axis
from edge.trackers.window import prepare_window
from edge.tracking import StageTimes
from tests.support.track import COLORS, SynthRover, shared_scene

MARKER_AREA = 22.0 * 17.0


def measure(method, image, rover: SynthRover, offset_px=(0.0, 0.0), background=None, tracker=None):
    """Run one tracker on a window around the rover's true position (as the pipeline prepares it)."""
    scene = shared_scene()
    config = TrackerConfig(rovers=(rover.config(), SynthRover("other", 0, 0, 0, COLORS["blue"]).config()))
    colors = ColorModel.from_colors([r.color_bgr for r in config.rovers], 30.0, 0.35)
    maps = PlaneGrid(scene.mapping, (image.shape[1], image.shape[0]))
    uv = scene.camera.project(np.array([[rover.x, rover.y, MARKER_HEIGHT_CM]]))[0] + np.asarray(offset_px)
    local = maps.at(*uv)
    r = config.marker_radius_cm + 6.0
    us, vs = local.to_pixel(rover.x + r * np.array([-1, 1, 1, -1.0]), rover.y + r * np.array([-1, -1, 1, 1.0]))
    box = (int(us.min()) - 3, int(vs.min()) - 3, int(us.max()) + 4, int(vs.max()) + 4)
    window = _window(image, box, uv, colors, maps, BackgroundModel(image.shape[:2], 100, background))
    tracker = tracker or make_tracker(method)
    return tracker.measure(window, RoverModel(0, MARKER_AREA, 0.0), StageTimes())


PLACES = [(60.0, 30.0, 0.0), (200.0, 150.0, 0.7), (330.0, 280.0, 2.0), (120.0, 420.0, -1.2), (250.0, 535.0, 0.3)]


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(("x", "y", "theta"), PLACES)
def test_each_tracker_finds_the_marker_centre_to_a_fraction_of_a_centimetre(method, x, y, theta):
    scene = shared_scene()
    rover = SynthRover("red", x, y, theta, COLORS["red"])
    image = scene.render([rover], noise_sigma=2.0, rng=np.random.default_rng(int(x)))
    m = measure(method, image, rover)
    assert m is not None
    assert math.hypot(m.xy_cm[0] - x, m.xy_cm[1] - y) < 0.2
    assert m.area_cm2 == pytest.approx(MARKER_AREA, rel=0.15)


def test_world_centroid_removes_the_perspective_bias_of_the_pixel_centroid():
    """Far side: the pixel centroid of the marker, mapped to the plane, is not the marker's centre."""
    scene = shared_scene()
    x, y = 200.0, 530.0
    corners = np.array([[x - 8.5, y - 11, 13], [x + 8.5, y - 11, 13], [x + 8.5, y + 11, 13], [x - 8.5, y + 11, 13]])
    uv = scene.camera.project(corners)
    box = (int(uv[:, 0].min()) - 4, int(uv[:, 1].min()) - 4, int(uv[:, 0].max()) + 5, int(uv[:, 1].max()) + 5)
    x0, y0, x1, y1 = box
    # Coverage of the projected marker polygon, 64x supersampled.
    ss = 64
    big = np.zeros(((y1 - y0) * ss, (x1 - x0) * ss), np.uint8)
    poly = ((uv - [x0, y0] + 0.5) * ss - 0.5) * 256
    cv2.fillPoly(big, [np.rint(poly).astype(np.int32)], 255, shift=8)
    coverage = cv2.resize(big.astype(np.float32) / 255.0, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    blob = world_blob(coverage, (x0, y0), PlaneGrid(scene.mapping, (1280, 720)))
    assert blob is not None
    vs, us = np.mgrid[y0:y1, x0:x1]
    pixel_centroid = np.array([[(coverage * us).sum() / coverage.sum(), (coverage * vs).sum() / coverage.sum()]])
    mapped = scene.mapping.pixel_to_world(pixel_centroid)[0]
    assert math.hypot(blob.x_cm - x, blob.y_cm - y) < 0.03
    assert math.hypot(mapped[0] - x, mapped[1] - y) > 5 * math.hypot(blob.x_cm - x, blob.y_cm - y)
    assert blob.area_cm2 == pytest.approx(MARKER_AREA, rel=0.01)


@pytest.mark.parametrize("dist", [(0.0, 0.0), (0.1, -0.2), (-0.3, 0.1), (-0.25, 0.08)])
def test_plane_grid_follows_a_distorted_calibration_pixel_by_pixel(dist):
    from edge.camera import paper_camera
    from edge.trackers.base import CameraPlaneMapping

    mapping = CameraPlaneMapping(paper_camera(dist_coeffs=(*dist, 0.0, 0.0, 0.0)))
    grid = PlaneGrid(mapping, (1280, 720))
    rng = np.random.default_rng(1)
    pts = rng.integers([0, 110], [1280, 720], (4000, 2)).astype(np.float64)
    exact = mapping.pixel_to_world(pts)
    near_area = (exact[:, 0] > -50) & (exact[:, 0] < 440) & (exact[:, 1] > -50) & (exact[:, 1] < 600)
    pts, exact = pts[near_area], exact[near_area]
    x, y, area, valid = grid.map_pixels(pts[:, 0], pts[:, 1])
    assert valid.all()
    rows, cols = pts[:, 1].astype(int), pts[:, 0].astype(int)
    assert np.array_equal(grid.x_cm[rows, cols], x) and np.array_equal(grid.area_cm2[rows, cols], area)
    assert np.max(np.hypot(x - exact[:, 0], y - exact[:, 1])) < 0.02
    # The area per pixel is the Jacobian of the mapping: compare with finite differences of the calibration.
    half_u, half_v = np.array([0.5, 0.0]), np.array([0.0, 0.5])
    du = mapping.pixel_to_world(pts + half_u) - mapping.pixel_to_world(pts - half_u)
    dv = mapping.pixel_to_world(pts + half_v) - mapping.pixel_to_world(pts - half_v)
    jac = np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0])
    assert np.max(np.abs(area / jac - 1.0)) < 0.01


def test_plane_grid_marks_pixels_above_the_horizon_invalid():
    from edge.camera import PinholeCamera
    from edge.trackers.base import CameraPlaneMapping

    level = PinholeCamera.look_at((195.0, -200.0, 100.0), (195.0, 300.0, 60.0))  # horizon inside the image
    grid = PlaneGrid(CameraPlaneMapping(level), (1280, 720))
    assert grid.at(640.0, 5.0) is None
    assert grid.at(640.0, 700.0) is not None


@pytest.mark.parametrize(("method", "max_error_cm"), [("particles", 0.2), ("meanshift", 0.25)])
def test_a_speck_of_the_same_hue_beside_the_marker_is_ignored(method, max_error_cm):
    scene = shared_scene()
    rover = SynthRover("red", 150.0, 200.0, 0.0, COLORS["red"])
    image = scene.render([rover], noise_sigma=2.0)
    u, v = scene.camera.project(np.array([[rover.x + 19.0, rover.y + 4.0, 0.0]]))[0]
    image[int(v) - 3 : int(v) + 3, int(u) - 3 : int(u) + 3] = COLORS["red"]  # a red sticker on the floor
    m = measure(method, image, rover)
    assert m is not None
    assert math.hypot(m.xy_cm[0] - rover.x, m.xy_cm[1] - rover.y) < max_error_cm


def test_the_centroid_approach_is_pulled_by_a_speck_of_the_same_hue():
    """Table V: the centroid approach is 'affected' by noise (the filter then rejects the spike)."""
    scene = shared_scene()
    rover = SynthRover("red", 150.0, 200.0, 0.0, COLORS["red"])
    image = scene.render([rover], noise_sigma=2.0)
    u, v = scene.camera.project(np.array([[rover.x + 19.0, rover.y + 4.0, 0.0]]))[0]
    image[int(v) - 3 : int(v) + 3, int(u) - 3 : int(u) + 3] = COLORS["red"]
    m = measure("centroid", image, rover)
    assert m is not None
    assert math.hypot(m.xy_cm[0] - rover.x, m.xy_cm[1] - rover.y) > 0.5


@pytest.mark.slow
@pytest.mark.parametrize("offset", [(6.0, 0.0), (-4.0, 5.0), (0.0, -7.0)])
def test_mean_shift_climbs_to_the_marker_from_an_offset_prediction(offset):
    scene = shared_scene()
    rover = SynthRover("red", 180.0, 160.0, 0.4, COLORS["red"])
    image = scene.render([rover], noise_sigma=2.0)
    tracker = make_tracker("meanshift")
    measure("meanshift", image, rover, tracker=tracker)  # the first frame models the target
    m = measure("meanshift", image, rover, offset_px=offset, tracker=tracker)
    assert m is not None
    assert math.hypot(m.xy_cm[0] - rover.x, m.xy_cm[1] - rover.y) < 0.3


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_a_glare_spot_on_the_marker_is_filled_not_a_hole_in_the_estimate(method):
    scene = shared_scene()
    rover = SynthRover("green", 220.0, 140.0, 0.2, COLORS["green"])
    u, v = scene.camera.project(np.array([[rover.x + 3.0, rover.y + 2.0, MARKER_HEIGHT_CM]]))[0]
    image = scene.render([rover], noise_sigma=2.0, glare=(u, v, 3.0))
    config_rover = SynthRover("green", rover.x, rover.y, rover.theta, COLORS["green"])
    m = measure(method, image, config_rover)
    assert m is not None
    assert math.hypot(m.xy_cm[0] - rover.x, m.xy_cm[1] - rover.y) < 0.5
    assert m.area_cm2 == pytest.approx(MARKER_AREA, rel=0.2)


@pytest.mark.parametrize("method", METHODS)
def test_no_marker_in_the_window_gives_no_measurement(method):
    scene = shared_scene()
    rover = SynthRover("red", 150.0, 200.0, 0.0, COLORS["red"])
    m = measure(method, scene.floor.copy(), rover)
    assert m is None


def test_unknown_tracker_name_is_refused():
    with pytest.raises(ValueError, match="unknown tracking method"):
        make_tracker("kalman")


def _window(image, box, uv, colors, maps, background):
    """The window ``box`` of ``image`` for rover 0, predicted at image point ``uv`` (as the pipeline prepares it)."""
    window = prepare_window(
        image,
        box,
        rover_index=0,
        predicted_uv=(float(uv[0]), float(uv[1])),
        colors=colors,
        maps=maps,
        background=background,
        background_threshold=0.2,
        clock=NullClock(),
    )
    assert window is not None
    return window


def test_particles_choose_the_marker_nearest_the_prediction_in_a_window_far_from_the_image_origin():
    """Two markers of the same hue in one window (a rover meeting a red poster): the one the filter predicted is
    measured, wherever in the image the window lies (the particles' centres are in window pixels, the prediction
    in image pixels)."""
    scene = shared_scene()
    a = SynthRover("red", 200.0, 250.0, 0.0, COLORS["red"])
    b = SynthRover("red", 245.0, 290.0, 0.0, COLORS["red"])
    image = scene.render([a, b], noise_sigma=2.0, rng=np.random.default_rng(3))
    uv = scene.camera.project(np.array([[r.x, r.y, MARKER_HEIGHT_CM] for r in (a, b)]))
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    box = (int(lo[0]) - 40, int(lo[1]) - 40, int(hi[0]) + 41, int(hi[1]) + 41)
    config = TrackerConfig(rovers=(a.config(), SynthRover("other", 0, 0, 0, COLORS["blue"]).config()))
    colors = ColorModel.from_colors([r.color_bgr for r in config.rovers], 30.0, 0.35)
    maps = PlaneGrid(scene.mapping, (image.shape[1], image.shape[0]))
    bg = BackgroundModel(image.shape[:2], 100)
    for target in (a, b):
        i = 0 if target is a else 1
        window = _window(image, box, uv[i], colors, maps, bg)
        m = make_tracker("particles").measure(window, RoverModel(0, MARKER_AREA, 0.0), StageTimes())
        assert m is not None
        assert math.hypot(m.xy_cm[0] - target.x, m.xy_cm[1] - target.y) < 0.3


def test_particles_never_take_a_part_of_the_empty_scene_for_the_rover_when_another_particle_differs_from_it():
    """A poster of the rover's hue lies in the empty scene, just where the filter predicted the rover; the rover is
    35 cm away (three marker radii: farther than the nearness to the prediction alone would let it win). The poster
    is part of the empty scene (eq. 2: none of it differs from the reference), the rover is not: the rover is
    measured, however near the prediction the poster is."""
    scene = shared_scene()
    rover = SynthRover("red", 200.0, 285.0, 0.0, COLORS["red"])
    poster = SynthRover("poster", 200.0, 250.0, 0.0, (40, 35, 205), marker_cm=(22.0, 17.0), body_cm=(22.0, 17.0))
    image = scene.render([poster, rover], noise_sigma=2.0, rng=np.random.default_rng(5))
    empty = scene.render([poster])
    uv = scene.camera.project(np.array([[r.x, r.y, MARKER_HEIGHT_CM] for r in (poster, rover)]))
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    box = (int(lo[0]) - 40, int(lo[1]) - 40, int(hi[0]) + 41, int(hi[1]) + 41)
    config = TrackerConfig(rovers=(rover.config(), SynthRover("other", 0, 0, 0, COLORS["blue"]).config()))
    colors = ColorModel.from_colors([r.color_bgr for r in config.rovers], 30.0, 0.35)
    maps = PlaneGrid(scene.mapping, (image.shape[1], image.shape[0]))

    def measured(background: np.ndarray | None) -> tuple[float, float]:
        window = _window(image, box, uv[0], colors, maps, BackgroundModel(image.shape[:2], 100, background))
        m = make_tracker("particles").measure(window, RoverModel(0, MARKER_AREA, 0.0), StageTimes())
        assert m is not None
        return m.xy_cm

    assert math.dist(measured(empty), (rover.x, rover.y)) < 0.5
    assert math.dist(measured(None), (poster.x, poster.y)) < 0.5  # with no empty scene to tell, the nearer one


def _marker_on_a_body(theta: float, cm_per_px: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Luminance and marker coverage of a 21.5 x 16.8 cm marker on a dark body seen from above and in front: the
    body's top shows 2 px round the marker, its side below it, down to a foot outline that the camera sees turned
    by 12 degrees and smaller (another height: perspective and the lens). Rendered 8x finer, area-averaged, blurred
    by 0.8 px; the coverage keeps 0.05 on the 2-px ring round the marker (what unmixing leaves there)."""
    k, h, w, cx, cy = 8, 120, 120, 60.0, 50.0
    c, s = math.cos(theta), math.sin(theta)

    def rect(half_l: float, half_w: float) -> np.ndarray:
        corners = ((1, 1), (1, -1), (-1, -1), (-1, 1))
        return np.array(
            [[cx + a * c * half_l - b * s * half_w, cy + a * s * half_l + b * c * half_w] for a, b in corners]
        )

    def fill(img: np.ndarray, poly: np.ndarray, value: float) -> None:
        cv2.fillPoly(img, [np.round((poly + 0.5) * k - 0.5).astype(np.int32)], value)

    marker = rect(21.5 / 2 / cm_per_px, 16.8 / 2 / cm_per_px)
    top = rect(21.5 / 2 / cm_per_px + 2, 16.8 / 2 / cm_per_px + 2)
    turn = math.radians(12.0)
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    foot = (top - [cx, cy]) @ rot.T * 0.9 + [cx, cy + 6.0]
    big = np.full((h * k, w * k), 200.0, np.float32)  # the floor
    fill(big, cv2.convexHull(np.vstack([top, foot]).astype(np.float32))[:, 0, :], 30.0)  # the body's side
    fill(big, top, 45.0)
    cover = np.zeros((h * k, w * k), np.float32)
    fill(cover, marker, 1.0)
    big[cover > 0] = 110.0
    lum = cv2.GaussianBlur(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), (0, 0), 0.8)
    weights = cv2.resize(cover, (w, h), interpolation=cv2.INTER_AREA)
    weights[dilate(weights > 0, 2) & (weights == 0)] = 0.05
    return lum, weights


@pytest.mark.parametrize("degrees", [0.0, 20.0, 35.0, 60.0, 100.0])
def test_the_marker_axis_comes_from_its_own_edge_not_the_bodys_visible_side(degrees):
    """Taken over every gradient within two pixels of the coverage (the body's side and foot included), this axis
    was 2-3.6 degrees off; from the marker's own edge band, within half a degree."""
    theta = math.radians(degrees)
    lum, weights = _marker_on_a_body(theta)
    m = Measurement((0.0, 0.0), (60.0, 50.0), 361.0, 1.0, 1.0, theta + 0.05, 1.28, False, weights)
    axis, coherence = marker_axis((lum,), m, np.eye(2) * 0.5, np.ones(lum.shape, bool), (21.5, 16.8))
    assert abs(math.degrees(math.remainder(axis - theta, math.pi))) < 1.0
    assert coherence >= 0.3


def test_the_marker_axis_is_the_blobs_where_no_plane_shows_a_rectangle():
    lum, weights = _marker_on_a_body(0.3)
    m = Measurement((0.0, 0.0), (60.0, 50.0), 361.0, 1.0, 1.0, 0.31, 1.28, False, weights)
    flat = np.full(lum.shape, 50.0, np.float32)
    assert marker_axis((flat,), m, np.eye(2) * 0.5, np.ones(lum.shape, bool), (21.5, 16.8)) == (0.31, 0.0)


def test_another_rover_s_marker_is_its_hue_at_its_saturation_not_a_pale_body_of_that_hue():
    """A white body in the shade of a sunlit room is lit by the sky: pale blue, a fifth to a quarter of the blue
    marker's saturation (the family's sun clip). It is of the blue rover's hue class, but it is not a marker: the
    red marker's edge is unmixed against it (``edge.coverage``). A patch as saturated as the blue marker is one."""
    scene = shared_scene()
    colors = ColorModel.from_colors([COLORS["red"], COLORS["green"], COLORS["blue"]], 30.0, 0.35)
    blue = np.asarray(COLORS["blue"], np.float64)
    grey = np.full(3, blue.mean())
    image = np.full((480, 640, 3), 120, np.uint8)
    image[200:240, 300:330] = np.round(grey + 0.35 * (blue - grey)).astype(np.uint8)  # the pale body
    image[200:240, 330:360] = COLORS["blue"]  # another rover's marker
    image[210:230, 305:325] = COLORS["red"]  # this rover's marker, on the body
    maps = PlaneGrid(scene.mapping, (640, 480))
    window = prepare_window(
        image,
        (290, 190, 370, 250),
        rover_index=0,
        predicted_uv=(315.0, 220.0),
        colors=colors,
        maps=maps,
        background=BackgroundModel(image.shape[:2], 100),
        background_threshold=0.2,
        clock=NullClock(),
    )
    assert window is not None
    body = np.zeros(window.classes.shape, bool)
    body[11:49, 11:39] = True  # the pale body, a pixel in from its edges (window coordinates) ...
    body[19:41, 14:36] = False  # ... around the red marker
    others, markers = window.others(0), window.other_markers(0, (slice(0, 60), slice(0, 80)))
    assert others is not None and markers is not None
    assert others[body].all()  # of the blue rover's hue class ...
    assert not markers[body].any()  # ... but not its marker
    assert markers[11:49, 41:69].all()  # the blue marker is


@pytest.mark.parametrize("y_cm", [60.0, 275.0, 480.0])
def test_the_pixels_a_marker_covers_are_its_outline_s_area_in_the_image(y_cm: float) -> None:
    """What a marker's heading is weighed by: a 21.5 x 16.8 cm marker covers about 1640 pixels on the near side of
    the paper's floor (y 60 cm), 505 in the middle and 225 on the far side (y 480)."""
    scene = shared_scene()
    maps = PlaneGrid(scene.mapping, (1280, 720))
    corners = np.array([[-10.75, -8.4], [10.75, -8.4], [10.75, 8.4], [-10.75, 8.4]]) + np.array([200.0, y_cm])
    uv = scene.camera.project(np.column_stack([corners, np.full(4, MARKER_HEIGHT_CM)]))
    outline_px = cv2.contourArea(uv.astype(np.float32))
    centre = scene.camera.project(np.array([[200.0, y_cm, MARKER_HEIGHT_CM]]))[0]
    assert maps.pixels_of(21.5 * 16.8, *centre) == pytest.approx(outline_px, rel=0.03)
    assert 200.0 < maps.pixels_of(21.5 * 16.8, *centre) < 1700.0
    # a point off the image is taken at the nearest pixel on it
    assert maps.pixels_of(21.5 * 16.8, -50.0, centre[1]) == pytest.approx(maps.pixels_of(21.5 * 16.8, 0.0, centre[1]))


def test_negative_shares_beside_a_whole_marker_are_no_part_of_its_shape():
    """The coverage keeps shares down to -0.5 beyond the edge (noise there averages out of the centre). Rows of
    them beside a whole marker (a rim the surround's colours miss: the family's drift clip, seed 14641 on wood,
    a blue marker on a white body in every third frame) took its second moments off the marker's and made its
    elongation 2-3 or infinite, and it was refused on its shape. The shape is taken without them; the centre and
    the area keep them."""
    from edge.camera import paper_camera
    from edge.trackers.base import CameraPlaneMapping
    from edge.trackers.plane import SHAPE_RECHECK, shape_elongation

    grid = PlaneGrid(CameraPlaneMapping(paper_camera()), (1280, 720))
    u, v = (round(float(c)) for c in paper_camera().project(np.array([[150.0, 420.0, 13.0]]))[0])
    weights = np.zeros((40, 60), np.float32)
    weights[12:28, 15:45] = 1.0  # a whole marker (its pixels, near the far side)
    offset = (u - 30, v - 20)
    whole = world_blob(weights, offset, grid)
    assert whole is not None and whole.elongation < SHAPE_RECHECK
    ringed = weights.copy()
    ringed[8:12, 15:45] = ringed[28:32, 15:45] = -0.5  # beyond both long sides (the body's rims)
    blob = world_blob(ringed, offset, grid)
    assert blob is not None and blob.elongation > 2.0 * whole.elongation  # their moments taken off the marker's
    assert shape_elongation(ringed, offset, grid, blob) == pytest.approx(whole.elongation, rel=1e-9)
    assert shape_elongation(weights, offset, grid, whole) == whole.elongation  # nothing to take again
    assert blob.area_cm2 < whole.area_cm2  # the area keeps the negative shares
