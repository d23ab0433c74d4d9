"""The simulator's exact calibration: what the runtime derives from a known camera."""

from __future__ import annotations

import numpy as np
import pytest

from edge.calibration.exact import exact_calibration
from edge.camera import MARKER_HEIGHT_CM, paper_camera


@pytest.mark.parametrize("distortion", [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.12, 0.04, 0.0008, -0.0005, 0.0)])
def test_exact_calibration_maps_the_cameras_own_pixels_back_to_the_floor(distortion: tuple[float, ...]) -> None:
    camera = paper_camera(distortion)
    cal = exact_calibration(camera)
    gx, gy = np.meshgrid(np.linspace(10, 380, 7), np.linspace(10, 540, 9))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    uv = camera.project(np.column_stack([xy, np.full(len(xy), MARKER_HEIGHT_CM)]))
    assert np.abs(cal.pixel_to_world(uv) - xy).max() < 1e-6
    assert cal.image_size == (camera.width_px, camera.height_px)
