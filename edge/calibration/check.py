"""Checking a calibration against points surveyed but not used in its fit: the independent accuracy figure."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge.calibration.files import Calibration
from edge.calibration.points import PointTable
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]


class ErrorStats:
    """Count, mean, max and RMS of ``error_cm`` (N,) distances in cm; NaN when there are none."""

    error_cm: FloatArray

    @property
    def n(self) -> int:
        return int(self.error_cm.size)

    @property
    def mean_cm(self) -> float:
        return float(self.error_cm.mean()) if self.n else float("nan")

    @property
    def max_cm(self) -> float:
        return float(self.error_cm.max()) if self.n else float("nan")

    @property
    def rms_cm(self) -> float:
        return float(np.sqrt(np.mean(self.error_cm**2))) if self.n else float("nan")


@dataclass(frozen=True)
class CheckResult(ErrorStats):
    """``mapped_cm``: (N, 2) where the calibration puts each check point's pixel; ``error_cm``: (N,) distance to
    its surveyed position."""

    table: PointTable
    mapped_cm: FloatArray
    error_cm: FloatArray


def check_calibration(cal: Calibration, table: PointTable) -> CheckResult:
    """Map the pixels of independently measured points and compare with their surveyed positions."""
    if len(table) == 0:
        raise CalibrationError(f"{table.source}: no check points")
    w, h = cal.image_size
    for i, (u, v) in enumerate(table.uv_px):
        if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
            raise CalibrationError(f"{table.where(i)}: pixel ({u:g}, {v:g}) is outside the {w}x{h} image")
    mapped = cal.pixel_to_world(table.uv_px)
    bad = np.flatnonzero(~np.all(np.isfinite(mapped), axis=1))
    if bad.size:
        raise CalibrationError(f"{table.where(int(bad[0]))}: pixel does not see the marker plane (above the horizon)")
    return CheckResult(table, mapped, np.linalg.norm(mapped - table.xy_world_cm, axis=1))


def check_summary(result: CheckResult, calibration_path: Path, points_path: Path) -> dict[str, Any]:
    """``edge-ips calibrate check --json``: the figures and every point (mapped position and error, 4 decimals)."""
    t = result.table
    points = [
        {
            "row": int(t.rows[i]),
            "u": float(t.uv_px[i, 0]),
            "v": float(t.uv_px[i, 1]),
            "x": float(t.xy_world_cm[i, 0]),
            "y": float(t.xy_world_cm[i, 1]),
            "x_mapped": round(float(result.mapped_cm[i, 0]), 4),
            "y_mapped": round(float(result.mapped_cm[i, 1]), 4),
            "error_cm": round(float(result.error_cm[i]), 4),
        }
        for i in range(result.n)
    ]
    return {
        "calibration": str(calibration_path),
        "points_file": str(points_path),
        "n": result.n,
        "mean_cm": round(result.mean_cm, 4),
        "max_cm": round(result.max_cm, 4),
        "rms_cm": round(result.rms_cm, 4),
        "points": points,
    }
