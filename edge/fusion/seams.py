"""One world frame across boards: how well neighbouring boards' calibrations agree where their views overlap.

Every board is calibrated into the same floor coordinates (survey points, or ArUco markers, measured in one frame
for the whole arena). A point surveyed once and seen by two boards is mapped by each board's calibration from its
own pixel; the distance between the two mapped positions is the **seam error** there: what a rover passing from one
view to the next would jump if nothing smoothed it, and what the fusion's covariances must cover. The surveyed
position is not needed for it (two boards can be compared on markers nobody measured), but when it is known each
board's own error is reported too (:func:`edge.calibration.check.check_calibration`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from edge.calibration.check import CheckResult, ErrorStats, check_calibration
from edge.calibration.files import Calibration
from edge.calibration.points import PointTable

FloatArray = NDArray[np.float64]

MATCH_CM = 0.5  # two boards' check points are the same surveyed point when their x, y agree this well


@dataclass(frozen=True)
class BoardCheck:
    """One board's calibration against its check points."""

    name: str
    calibration_path: Path
    check: CheckResult


@dataclass(frozen=True)
class Seam(ErrorStats):
    """Two boards compared on the points both see: ``xy_world_cm`` (N, 2) surveyed, ``error_cm`` (N,) distance
    between where board ``a`` and board ``b`` put each."""

    a: str
    b: str
    xy_world_cm: FloatArray
    error_cm: FloatArray


def board_name(calibration_path: Path) -> str:
    """``cam2/calibration.json`` -> ``cam2``; ``cam2.json`` -> ``cam2``."""
    return calibration_path.parent.name if calibration_path.stem == "calibration" else calibration_path.stem


def check_boards(boards: Sequence[tuple[Path, Calibration, PointTable]]) -> list[BoardCheck]:
    """Each board's calibration against its own check points (the names must differ)."""
    out = []
    for path, cal, table in boards:
        out.append(BoardCheck(board_name(path), path, check_calibration(cal, table)))
    return out


def seams(checks: Sequence[BoardCheck]) -> list[Seam]:
    """Every pair of boards that share check points (same surveyed x, y), compared point by point."""
    out = []
    for i, a in enumerate(checks):
        for b in checks[i + 1 :]:
            xy_a, xy_b = a.check.table.xy_world_cm, b.check.table.xy_world_cm
            if len(xy_a) == 0 or len(xy_b) == 0:
                continue
            dist = np.linalg.norm(xy_a[:, None, :] - xy_b[None, :, :], axis=2)
            ia, ib = np.nonzero(dist <= MATCH_CM)
            if ia.size == 0:
                continue
            error = np.linalg.norm(a.check.mapped_cm[ia] - b.check.mapped_cm[ib], axis=1)
            out.append(Seam(a.name, b.name, xy_a[ia], error))
    return out
