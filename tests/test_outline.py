"""The marker's centre from its fitted outline (edge.outline): where the marker is, whatever surrounds it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.camera import paper_camera
from edge.outline import fit_edges, fit_outline, marker_signal
from edge.segmentation import linear_bgr
from edge.sim.effects import Compression, Effects, Optics, SunPatch
from edge.sim.render import Renderer
from edge.sim.scene import BLUE_BGR, RED_BGR, RoverLook, Scene, marker_albedo_for_hue
from edge.sim.world import RoverState, WorldState
from edge.trackers.base import CameraPlaneMapping, PlaneGrid
from edge.two_tone import footprint_cm

SIZE = (21.5, 16.8)
BODIES = {"black": (0.035, 0.034, 0.032), "dark grey": (0.12, 0.12, 0.12), "white": (0.8, 0.8, 0.8)}


@pytest.fixture(scope="module")
def grid() -> PlaneGrid:
    return PlaneGrid(CameraPlaneMapping(paper_camera()), (1280, 720))


def _fit(grid: PlaneGrid, image: np.ndarray, truth: tuple[float, float, float], start_offset_cm=(0.4, -0.3)):
    """Fit the outline of the marker at ``truth`` (x, y, theta) in ``image``, starting a little off."""
    x, y, th = truth
    uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
    local = grid.at(*uv)
    assert local is not None
    _, _, su, sv = local.pixel_of(x, y)
    r = 16.0
    x0, y0 = int(uv[0] - r * su) - 6, int(uv[1] - r * sv) - 6
    x1, y1 = int(uv[0] + r * su) + 7, int(uv[1] + r * sv) + 7
    xs, ys = grid.x_cm[y0:y1, x0:x1], grid.y_cm[y0:y1, x0:x1]
    along = (xs - x) * math.cos(th) + (ys - y) * math.sin(th)
    across = (ys - y) * math.cos(th) - (xs - x) * math.sin(th)
    interior = (np.abs(along) < SIZE[0] / 2 - 3.0) & (np.abs(across) < SIZE[1] / 2 - 3.0)
    signal = marker_signal(linear_bgr(image[y0:y1, x0:x1]), interior)
    assert signal is not None
    jac = local.jacobian(*uv)
    start = (x + start_offset_cm[0], y + start_offset_cm[1])
    axis = th + math.radians(0.5)
    return fit_outline(signal, xs, ys, start, axis, SIZE, footprint_cm(jac, axis))


def _render(look: RoverLook, pose: tuple[float, float, float], effects: Effects) -> np.ndarray:
    renderer = Renderer(paper_camera(), Scene((look,)), effects)
    return renderer.render(WorldState(0.0, (RoverState(look.rover_id, *pose, 0.0, 0.0, 0.0),)), 0)


def _effects(blur_px: float, compression: Compression | None = None, sun: SunPatch | None = None) -> Effects:
    return Effects(
        auto_exposure=None, noise=None, motion_blur=False, optics=Optics(blur_px), compression=compression, sun=sun
    )


@pytest.mark.slow
@pytest.mark.parametrize("body", list(BODIES))
@pytest.mark.parametrize("blur_px", [0.5, 1.2])
@pytest.mark.parametrize(
    ("colour", "pose"),
    [
        (BLUE_BGR, (200.0, 460.0, 0.3)),  # far side: 2.3 cm per pixel along y, the body's side towards the camera
        (RED_BGR, (90.0, 120.0, 2.0)),
        (marker_albedo_for_hue(55.0), (300.0, 300.0, -1.2)),  # yellow: as bright as the floor
    ],
)
def test_the_outline_puts_the_centre_where_the_marker_is_whatever_body_and_blur(grid, body, blur_px, colour, pose):
    """A coverage-weighted centroid of 8-bit values was pulled 0.4 cm towards the camera by a black body and a
    1.2 px blur; the fitted edges in linear light are not."""
    look = RoverLook("r", colour, body_bgr=BODIES[body])
    fit = _fit(grid, _render(look, pose, _effects(blur_px)), pose)
    assert fit is not None
    assert math.hypot(fit.xy_cm[0] - pose[0], fit.xy_cm[1] - pose[1]) < 0.08  # 0.03 px at the far side
    assert fit.size_cm == pytest.approx(SIZE, abs=0.4)


@pytest.mark.slow
@pytest.mark.parametrize("chroma", ["4:4:4", "4:2:2"])
def test_the_outline_holds_through_a_webcams_mjpg(grid, chroma):
    look = RoverLook("r", BLUE_BGR)
    errors = []
    for k, pose in enumerate([(200.0, 460.0, 0.3), (120.0, 300.0, 1.1), (320.0, 150.0, -0.4), (60.0, 500.0, 2.5)]):
        fit = _fit(grid, _render(look, pose, _effects(0.7, Compression(90, chroma))), pose)
        assert fit is not None, k
        errors.append(math.hypot(fit.xy_cm[0] - pose[0], fit.xy_cm[1] - pose[1]))
    assert max(errors) < 0.2  # JPEG's quantised chroma: 0.1 px at the far side


@pytest.mark.slow
def test_a_marker_half_in_a_sunlit_patch_keeps_its_centre(grid):
    """The sunlit half of the marker is 2.4 times brighter: each edge fits its own marker level."""
    sun = SunPatch(strength=1.4, cloud_depth=0.0)
    patch = sun.patch_cm(13.0)
    x_edge = float(patch[:, 0].min())  # the patch's left edge at the marker's height
    pose = (x_edge + 2.0, float(patch[:, 1].mean()), 0.0)
    look = RoverLook("r", BLUE_BGR)
    fit = _fit(grid, _render(look, pose, _effects(0.7, sun=sun)), pose)
    assert fit is not None
    assert math.hypot(fit.xy_cm[0] - pose[0], fit.xy_cm[1] - pose[1]) < 0.08


@pytest.mark.slow
def test_a_marker_with_an_edge_hidden_gives_no_outline(grid):
    pose = (150.0, 250.0, 0.0)
    image = _render(RoverLook("r", RED_BGR), pose, _effects(0.6))
    x, y, th = pose
    uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
    local = grid.at(*uv)
    x0, y0 = int(uv[0]) - 60, int(uv[1]) - 40
    xs, ys = grid.x_cm[y0 : y0 + 80, x0 : x0 + 120], grid.y_cm[y0 : y0 + 80, x0 : x0 + 120]
    interior = (np.abs(xs - x) < 6.0) & (np.abs(ys - y) < 4.0)
    signal = marker_signal(linear_bgr(image[y0 : y0 + 80, x0 : x0 + 120]), interior)
    hidden = xs > x + 5.0  # a leg over the marker's front third
    jac = local.jacobian(*uv)
    assert fit_outline(signal, xs, ys, (x, y), th, SIZE, footprint_cm(jac, th), usable=~hidden) is None


@pytest.mark.parametrize("margin_cm", [0.0, 0.4, 1.5])
@pytest.mark.parametrize("floor_level", [-0.03, 0.0, 0.04])
def test_an_edge_is_found_between_marker_body_margin_and_tinted_floor(margin_cm, floor_level):
    """One edge's profile: marker (0.3), a margin of neutral body (0), the floor beyond with a faint tint along the
    marker's colour, blurred by 1 cm and sampled at 0.5 cm pixels; the fit finds the marker's step at 0: exactly
    without noise, and without bias with it (noise of 0.7 % of the marker's level moves it by a few hundredths)."""

    d = np.linspace(-4.0, 4.0, 161)
    w = 1.0
    clean = 0.3 * _step(-d / w) + floor_level * _step((d - margin_cm) / w)
    exact = fit_edges([(d, clean, 0.5)], 0.3)
    assert exact is not None
    assert abs(float(exact[0][0])) < 1e-3 and float(exact[1][0]) == pytest.approx(w, rel=1e-3)
    found = []
    for seed in range(12):
        noisy = clean + np.random.default_rng(seed).normal(0.0, 0.002, d.size)
        fitted = fit_edges([(d, noisy, 0.5)], 0.3)
        assert fitted is not None
        found.append(float(fitted[0][0]))
    assert abs(float(np.mean(found))) < 0.05
    assert max(abs(e) for e in found) < 0.12


def _step(z: np.ndarray) -> np.ndarray:
    return np.asarray([0.5 * (1.0 + math.erf(float(v) / math.sqrt(2.0))) for v in z])
