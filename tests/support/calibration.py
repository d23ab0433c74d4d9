"""Shared helpers for the calibration tests: ground truth over the working area, synthetic scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edge.calibration.files import Calibration
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM, PinholeCamera

DISTORTION = (-0.12, 0.04, 0.0008, -0.0005, 0.0)  # a C920-like mild barrel lens
PAPER_MEAN_CM, PAPER_MAX_CM = 0.659, 1.148


def dense_area(n_x: int = 60, n_y: int = 80) -> np.ndarray:
    """(n_x * n_y, 2) a dense grid over the whole working area, edges included."""
    gx, gy = np.meshgrid(np.linspace(0.0, AREA_WIDTH_CM, n_x), np.linspace(0.0, AREA_LENGTH_CM, n_y))
    return np.column_stack([gx.ravel(), gy.ravel()])


def true_errors_cm(cal: Calibration, camera: PinholeCamera, z_cm: float = MARKER_HEIGHT_CM) -> np.ndarray:
    """(N,) distance between each dense-grid world point and where ``cal`` maps its exact (lens) pixel."""
    xy = dense_area()
    uv = camera.project(np.column_stack([xy, np.full(xy.shape[0], z_cm)]))
    return np.asarray(np.linalg.norm(cal.pixel_to_world(uv) - xy, axis=1))


def write_csv(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text("\n".join([header, *rows]) + "\n")
    return path
