"""The acquisition pass: where a lost rover's marker may be, from one cheap pass over a low-resolution copy of the
frame (first frame, and whenever a rover is lost). The pipeline then measures each candidate at full resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.segmentation import F32, ColorModel, opponent_planes
from edge.trackers.base import SURROUND_IGNORED, PlaneGrid, PlaneMapping, sampled_median
from edge.trackers.plane import WithWorkingArea
from edge.white import LocalWhite

CANDIDATES_PER_ROVER = 6  # the blobs of a rover's hue class tried, the strongest in its colour plane first


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


@dataclass(frozen=True)
class LowResolution:
    """A 1/``scale`` copy of the frame seen under the configured white: each pixel's hue class (-1: none) and its
    opponent chroma planes (the rovers' colour planes are their projections)."""

    classes: NDArray[np.int16]
    c1: F32
    c2: F32
    scale: int


def low_resolution_view(
    image: NDArray[np.uint8], scale: int, colors: ColorModel, white: LocalWhite | None
) -> LowResolution:
    """The hue classes and chroma of a 1/``scale`` copy of ``image``, seen under the configured white."""
    h, w = image.shape[:2]
    small = (
        np.asarray(cv2.resize(image, (w // scale, h // scale), interpolation=cv2.INTER_AREA), np.uint8)
        if scale > 1
        else image
    )
    if white is not None:
        small = white.correct(small, white.frame_gains(small.shape[:2]))
    c1, c2, lum = opponent_planes(small)
    return LowResolution(colors.classify(c1, c2, lum), c1, c2, scale)


def candidates(view: LowResolution, index: int, colors: ColorModel) -> list[tuple[float, float]]:
    """Full-resolution image places of the blobs of rover ``index``'s hue class, the strongest in its colour plane
    first (each blob's peak), :data:`CANDIDATES_PER_ROVER` at most. A blob's strong part is its pixels halfway from
    the floor's level to its peak or more (the floor's level: the frame's median in the rover's plane, less
    ``SURROUND_IGNORED`` of the peak, 0 at least, as ``edge.trackers.base.surrounded`` takes it in a window); each
    connected strong part is a candidate, placed at its strength-weighted centre.

    A marker is its hue at its full strength; a camera's white balance and crosstalk can give the floor a weak cast
    of the same hue in patches larger than a marker (the family's cross clip with seed 7777, a 4:4:4 camera with
    14 % crosstalk and a warm white balance: six floor patches at a sixth of the red marker's strength, each larger
    than it, were tried and refused while the parked red rover went unfound for 1.7 s; ranked by area, the marker
    was never tried), and such a patch can touch the marker and make one blob with it (occlusion 11404: its centre
    23 px from the marker's, whose window then missed it for 2 s). On a floor of the marker's hue class (warm wood
    under a red or orange marker) the whole floor is one blob with the marker, at about half its strength: half the
    peak took in the stronger planks, and the candidate, their centre with the marker's, lay far from it (the
    family's crowd clip with seed 4321 on wood: the orange marker was never tried)."""
    mask = (view.classes == index).view(np.uint8)
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    if n <= 1:
        return []
    plane = colors.plane(index, view.c1, view.c2)
    where = np.flatnonzero(mask)
    label = labels.ravel()[where]
    value = plane.ravel()[where].astype(np.float64)
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, label, value)
    # each blob's strong part: halfway from the floor's level to its peak (edge.trackers.base.surrounded)
    floor = sampled_median(plane) - SURROUND_IGNORED * peak[label]  # the floor fills most of a frame
    level = np.where(floor > 0.0, floor, 0.0)
    strong = value >= level + 0.5 * (peak[label] - level)
    keep = np.zeros(mask.size, np.uint8)
    keep[where[strong]] = 1
    n, labels = cv2.connectedComponents(keep.reshape(mask.shape), connectivity=8)
    where = where[strong]
    label = labels.ravel()[where]
    weight = value[strong]
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, label, weight)
    total = np.bincount(label, weight, minlength=n)
    rows, cols = np.divmod(where, mask.shape[1])
    u = np.bincount(label, weight * cols, minlength=n) / np.maximum(total, 1e-9)
    v = np.bincount(label, weight * rows, minlength=n) / np.maximum(total, 1e-9)
    order = np.argsort(-peak[1:], kind="stable")[:CANDIDATES_PER_ROVER] + 1
    s = view.scale
    return [((float(u[k]) + 0.5) * s - 0.5, (float(v[k]) + 0.5) * s - 0.5) for k in order.tolist()]
