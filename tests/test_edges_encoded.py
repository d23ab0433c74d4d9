"""Marker edges fitted in the camera's encoded chroma (edge.edges_encoded): single frames of a marker at known poses
through the simulator's camera and JPEG streams, the default centre (edge.coverage) as the start, as in
``benchmarks/bench_chroma_bias.py --centre edges`` (more poses, bodies, margins and palettes there)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.camera import paper_camera
from edge.coverage import coverage_weights
from edge.edges_encoded import encoded_edge_centre
from edge.segmentation import erode
from edge.sim.effects import Compression, Effects, Optics
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


def _errors_cm(grid: PlaneGrid, compression: Compression | None, blur_px: float) -> np.ndarray:
    """(len(POSES), 2, 2): per pose the default centre's and the fitted edges' (x, y) error."""
    effects = Effects(
        auto_exposure=None, noise=None, motion_blur=False, optics=Optics(blur_px), compression=compression
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
        fitted = encoded_edge_centre(roi, xy, erode(core, 2), (blob.x_cm, blob.y_cm), th, SIZE_CM)
        assert fitted is not None
        (ex, ey), _ = fitted
        out.append([(blob.x_cm - x, blob.y_cm - y), (ex - x, ey - y)])
    return np.asarray(out)


@pytest.mark.parametrize("blur_px", [0.5, 1.2])
def test_edges_in_the_encoded_chroma_take_the_4_2_0_spread_out_of_the_centre(grid, blur_px):
    """4:2:0 at quality 90 on a black body: the default centre moves 0.2-0.4 cm away from the camera (the spread
    chroma counts more on the bright floor once linearised); the fitted edges' centre is within 0.06 cm on average
    and 0.25 cm on every pose."""
    errors = _errors_cm(grid, Compression(90, "4:2:0"), blur_px)
    assert errors[:, 0, 1].mean() > 0.15, errors  # the bias this is about
    assert float(np.hypot(*errors[:, 1].mean(axis=0))) < 0.06, errors
    assert float(np.hypot(errors[:, 1, 0], errors[:, 1, 1]).max()) < 0.25, errors


def test_edges_in_the_encoded_chroma_hold_on_uncompressed_frames(grid):
    """No stream: the fitted edges' centre is as good as the default one (within 0.04 cm on average)."""
    errors = _errors_cm(grid, None, 0.5)
    assert float(np.hypot(*errors[:, 1].mean(axis=0))) < 0.04, errors
    assert float(np.hypot(errors[:, 1, 0], errors[:, 1, 1]).max()) < 0.15, errors
