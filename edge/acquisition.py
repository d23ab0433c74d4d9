"""The acquisition pass: where a lost rover's marker may be, from one cheap pass over a low-resolution copy of the
frame (first frame, and whenever a rover is lost). The pipeline then measures each candidate at full resolution.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.segmentation import ColorModel, opponent_planes
from edge.trackers.base import PlaneGrid, PlaneMapping
from edge.trackers.plane import WithWorkingArea
from edge.white import LocalWhite

CANDIDATES_PER_ROVER = 6  # the largest blobs of a rover's hue class tried, largest first


def acquisition_scale(marker_area_cm2: float, max_scale: int, grid: PlaneGrid, calibration: PlaneMapping) -> int:
    """The acquisition pass's downscale: as coarse as ``max_scale`` allows while the smallest marker in the working
    area stays two low-resolution pixels across or more (4 for the paper's 1280x720 view, whose far-side markers
    are about 21 x 9 px; less for a smaller image or a farther camera)."""
    area = calibration.area_cm if isinstance(calibration, WithWorkingArea) else None
    x0, y0, x1, y1 = area or (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM)
    inside = (grid.area_cm2 > 0) & (grid.x_cm >= x0) & (grid.x_cm <= x1) & (grid.y_cm >= y0) & (grid.y_cm <= y1)
    if not inside.any():
        return max_scale
    smallest_px = marker_area_cm2 / float(grid.area_cm2[inside].max())
    short_side_px = math.sqrt(smallest_px / 2.5)  # perspective flattens far markers up to about 2.5:1
    return max(1, min(max_scale, int(short_side_px / 2.0)))


def low_resolution_classes(
    image: NDArray[np.uint8], scale: int, colors: ColorModel, white: LocalWhite | None
) -> NDArray[np.int16]:
    """Hue class per pixel (-1: none) of a 1/``scale`` copy of ``image``, seen under the configured white."""
    h, w = image.shape[:2]
    small = (
        np.asarray(cv2.resize(image, (w // scale, h // scale), interpolation=cv2.INTER_AREA), np.uint8)
        if scale > 1
        else image
    )
    if white is not None:
        small = white.correct(small, white.frame_gains(small.shape[:2]))
    c1, c2, lum = opponent_planes(small)
    return colors.classify(c1, c2, lum)


def candidates(classes: NDArray[np.int16], index: int, scale: int) -> list[tuple[float, float]]:
    """Full-resolution image centres of the largest blobs of rover ``index``'s hue class, largest first."""
    mask = (classes == index).view(np.uint8)
    n, _, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return []
    order = np.argsort(-stats[1:, cv2.CC_STAT_AREA])[:CANDIDATES_PER_ROVER] + 1
    return [
        ((float(cents[label, 0]) + 0.5) * scale - 0.5, (float(cents[label, 1]) + 0.5) * scale - 0.5)
        for label in order.tolist()
        if stats[label, cv2.CC_STAT_AREA] >= 1
    ]
