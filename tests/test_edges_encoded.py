"""Marker edges fitted in the camera's encoded chroma (edge.edges_encoded): single frames of a marker at known poses
through the simulator's camera and JPEG streams, the default centre (edge.coverage) as the start, as in
``benchmarks/bench_chroma_bias.py --centre edges`` (more poses, bodies, margins and palettes there)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from edge.camera import paper_camera
from edge.coverage import coverage_weights
from edge.edges_encoded import YCC_FROM_BGR, edge_midpoint, encoded_edge_centre, fit_edges, side_profiles
from edge.edges_held import fit_edges_held, hold
from edge.segmentation import erode
from edge.sim.effects import Compression, Effects, Optics, SignalProcessing
from edge.sim.render import Renderer
from edge.sim.scene import BLUE_BGR, GREEN_BGR, RoverLook, Scene
from edge.sim.world import RoverState, WorldState
from edge.trackers.base import CameraPlaneMapping, PlaneGrid
from edge.trackers.plane import world_blob

SIZE_CM = (21.5, 16.8)
BLACK = (0.035, 0.034, 0.032)
# near and far side, turned every way
POSES = ((73.0, 470.0, 0.4), (310.0, 120.0, -1.9), (205.0, 330.0, 2.6), (120.0, 210.0, 1.2))


@pytest.fixture(scope="module")
def grid() -> PlaneGrid:
    return PlaneGrid(CameraPlaneMapping(paper_camera()), (1280, 720))


def _frames(
    grid: PlaneGrid, compression: Compression | None, blur_px: float, processing: SignalProcessing | None = None
) -> list[Frame]:
    """Per pose: the window, its pixels on the plane, the marker's interior, the default centre, the pose."""
    effects = Effects(
        auto_exposure=None,
        noise=None,
        motion_blur=False,
        optics=Optics(blur_px),
        compression=compression,
        processing=processing,
    )
    out = []
    for k, pose in enumerate(POSES):
        look = RoverLook("r", BLUE_BGR if k % 2 else GREEN_BGR, body_bgr=BLACK)
        image = Renderer(paper_camera(), Scene((look,)), effects).render(
            WorldState(0.0, (RoverState("r", *pose, 0.0, 0.0, 0.0),)), 0
        )
        x, y, th = pose
        uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
        x0, y0 = int(uv[0]) - 60, int(uv[1]) - 50
        window = (slice(y0, y0 + 100), slice(x0, x0 + 120))
        xy = grid.xy_cm[:, window[0], window[1]]
        along = (xy[0] - x) * math.cos(th) + (xy[1] - y) * math.sin(th)
        across = (xy[1] - y) * math.cos(th) - (xy[0] - x) * math.sin(th)
        core = (np.abs(along) < SIZE_CM[0] / 2) & (np.abs(across) < SIZE_CM[1] / 2)
        roi = np.ascontiguousarray(image[window])
        blob = world_blob(coverage_weights(roi, core, 2, pure=core), (x0, y0), grid)
        assert blob is not None
        out.append(Frame(roi, xy, erode(core, 2), (blob.x_cm, blob.y_cm), pose))
    return out


@dataclass(frozen=True)
class Frame:
    roi: np.ndarray
    xy: np.ndarray
    interior: np.ndarray
    start: tuple[float, float]
    pose: tuple[float, float, float]


def _errors_cm(grid: PlaneGrid, compression: Compression | None, blur_px: float) -> np.ndarray:
    """(len(POSES), 2, 2): per pose the default centre's and the fitted edges' (x, y) error."""
    out = []
    for f in _frames(grid, compression, blur_px):
        fitted = encoded_edge_centre(f.roi, f.xy, f.interior, f.start, f.pose[2], SIZE_CM)
        assert fitted is not None
        (ex, ey), _ = fitted
        x, y = f.pose[:2]
        out.append([(f.start[0] - x, f.start[1] - y), (ex - x, ey - y)])
    return np.asarray(out)


@pytest.mark.slow
@pytest.mark.parametrize("blur_px", [0.5, 1.2])
def test_edges_in_the_encoded_chroma_take_the_4_2_0_spread_out_of_the_centre(grid, blur_px):
    """4:2:0 at quality 90 on a black body: the default centre moves 0.2-0.4 cm away from the camera (the spread
    chroma counts more on the bright floor once linearised); the fitted edges' centre is within 0.06 cm on average
    and 0.25 cm on every pose."""
    errors = _errors_cm(grid, Compression(90, "4:2:0"), blur_px)
    assert errors[:, 0, 1].mean() > 0.15, errors  # the bias this is about
    assert float(np.hypot(*errors[:, 1].mean(axis=0))) < 0.06, errors
    assert float(np.hypot(errors[:, 1, 0], errors[:, 1, 1]).max()) < 0.25, errors


@pytest.mark.slow
def test_edges_in_the_encoded_chroma_hold_on_uncompressed_frames(grid):
    """No stream: the fitted edges' centre is as good as the default one (within 0.04 cm on average)."""
    errors = _errors_cm(grid, None, 0.5)
    assert float(np.hypot(*errors[:, 1].mean(axis=0))) < 0.04, errors
    assert float(np.hypot(errors[:, 1, 0], errors[:, 1, 1]).max()) < 0.15, errors


@pytest.mark.slow
def test_a_sharpening_cameras_luma_counts_less_and_moves_the_centre_less(grid):
    """A camera that sharpens its luma hard (an unsharp mask of 1.2 times the detail, no stream) on a black body: with
    luma and chroma weighed alike the fitted centre moves towards the camera (-y, 0.15 cm on average here: the sides
    beside the floor are taken inward more than the one beside the body's dark wall); fitted again with the luma
    weighed by the first fit's residuals (a fifth to a half here), at least a fifth of that goes (a quarter here;
    fitted again and again, the weights settle and take out little more)."""
    centres: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    for f in _frames(grid, None, 0.8, SignalProcessing(demosaic=None, sharpen=1.2)):
        profiles = side_profiles(f.roi, f.xy, f.start, f.pose[2], (SIZE_CM[0] / 2, SIZE_CM[1] / 2))
        marker_ycc = f.roi[f.interior].astype(np.float64).mean(axis=0) @ YCC_FROM_BGR.T
        for weigh, out in centres.items():
            fit = fit_edges(profiles, marker_ycc, side_levels=True, weigh_channels=weigh)
            x, y = edge_midpoint(f.start, f.pose[2], fit.u0_px, profiles)
            out.append((x - f.pose[0], y - f.pose[1]))
    alike, weighed = (np.asarray(centres[w]).mean(axis=0) for w in (False, True))
    assert alike[1] < -0.1, alike  # the pull this is about
    assert float(np.hypot(*weighed)) < 0.8 * float(np.hypot(*alike)), (weighed, alike)


@pytest.fixture(scope="module")
def stream_fits(grid):
    """4:2:0 at quality 90, blur 0.8 px: per pose the frame, its profiles, the marker's Y'CbCr and the full fit."""
    out = []
    for f in _frames(grid, Compression(90, "4:2:0"), 0.8):
        profiles = side_profiles(f.roi, f.xy, f.start, f.pose[2], (SIZE_CM[0] / 2, SIZE_CM[1] / 2))
        marker_ycc = f.roi[f.interior].astype(np.float64).mean(axis=0) @ YCC_FROM_BGR.T
        out.append((f, profiles, marker_ycc, fit_edges(profiles, marker_ycc)))
    return out


@pytest.mark.slow
def test_the_held_fit_on_a_frames_own_parameters_finds_the_full_fits_edges(stream_fits):
    """Held from the frame's own full fit, the per-frame fit (edge and margin per side) lands on the full fit's
    edges: the same model, the same minimum."""
    for _, profiles, marker_ycc, full in stream_fits:
        quick = fit_edges_held(profiles, marker_ycc, hold([full]))
        assert quick is not None
        np.testing.assert_allclose(quick.u0_px, full.u0_px, atol=0.01)
        assert quick.rms <= full.rms + 0.05


@pytest.mark.slow
def test_edges_on_a_model_held_from_other_frames_take_the_4_2_0_spread_out(stream_fits):
    """Each frame on the model held from the other poses' full fits (the camera's blur and spread, the body's
    level): the default centre's mean error of 0.2-0.3 cm towards far from the camera falls below 0.08 cm."""
    errors = []
    for k, (f, profiles, marker_ycc, _) in enumerate(stream_fits):
        held = hold([fit for j, (*_, fit) in enumerate(stream_fits) if j != k])
        quick = fit_edges_held(profiles, marker_ycc, held)
        assert quick is not None
        x, y = edge_midpoint(f.start, f.pose[2], quick.u0_px, profiles)
        errors.append([(f.start[0] - f.pose[0], f.start[1] - f.pose[1]), (x - f.pose[0], y - f.pose[1])])
    mean = np.asarray(errors).mean(axis=0)
    assert mean[0, 1] > 0.15, errors
    assert float(np.hypot(*mean[1])) < 0.08, errors


@pytest.mark.slow
def test_the_held_fit_refuses_profiles_not_centred_on_the_marker(stream_fits):
    """Profiles taken 2 cm off the marker along its axis: one edge lies beyond reach, the fit says so (None) instead
    of returning a centre."""
    f, _, marker_ycc, full = stream_fits[1]
    th = f.pose[2]
    off = (f.start[0] + 2.0 * math.cos(th), f.start[1] + 2.0 * math.sin(th))
    profiles = side_profiles(f.roi, f.xy, off, th, (SIZE_CM[0] / 2, SIZE_CM[1] / 2))
    assert fit_edges_held(profiles, marker_ycc, hold([full])) is None


@pytest.mark.slow
def test_the_side_by_side_jacobian_gives_the_fit_of_forward_differences_over_every_residual(grid, monkeypatch):
    """A side's edge and margin move only that side's residuals, so the fit differences that side alone for them
    (32 side models per Jacobian instead of 56); the fit is the same, to the last bit, as differencing every
    residual."""
    import edge.edges_encoded as encoded

    frames = _frames(grid, Compression(quality=70, chroma="4:2:0"), 0.8)[:2]
    fast = [encoded_edge_centre(f.roi, f.xy, f.interior, f.start, f.pose[2], SIZE_CM) for f in frames]
    plain_lm = encoded._levenberg_marquardt
    monkeypatch.setattr(
        encoded, "_levenberg_marquardt", lambda fun, x, iterations, jacobian=None: plain_lm(fun, x, iterations)
    )
    plain = [encoded_edge_centre(f.roi, f.xy, f.interior, f.start, f.pose[2], SIZE_CM) for f in frames]
    for a, b in zip(fast, plain, strict=True):
        assert a is not None and b is not None
        assert a[0] == b[0]
        assert np.array_equal(a[1].u0_px, b[1].u0_px) and a[1].rms == b[1].rms
