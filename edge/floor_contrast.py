"""How far each marker stands out from the floor in its own colour plane, from an empty-floor image.

The tracker takes a marker only where its level in its colour plane (its chroma along its hue) is
:data:`~edge.trackers.base.STANDOUT` times the floor's around it or more (``edge.trackers.base.surrounded``): a
floor of the marker's hue class, such as warm wood under a red or orange marker, can otherwise pass as the marker.
Enrolment (``edge.enroll``) measures, for each marker, its level against the empty floor's at the marker's place
and at the floor's most marker-like place in view, and says when a floor defeats a marker there, or nearly does.
Arrays in, dataclasses out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.segmentation import chroma_of_bgr, opponent_planes
from edge.trackers.base import STANDOUT, SURROUND_IGNORED, PlaneMapping

U8 = NDArray[np.uint8]
MARGINAL = 2.0  # under this many times the floor's level a marker is found only while its light and size hold
WINDOW_SIDES = 3.0  # the tracker's window around a marker, in marker sides (its radius plus the margin, each way)


@dataclass(frozen=True)
class FloorContrast:
    """One marker's level in its plane over the floor's there (``here``) and at the floor's most marker-like place
    (``worst``, at image pixel ``worst_uv_px``); ``math.inf`` where the floor's level is 0 (not of its hue)."""

    rover_id: str
    here: float
    worst: float
    worst_uv_px: tuple[float, float]


def floor_contrast(
    background: U8,
    rover_id: str,
    color_bgr: Sequence[int],
    uv_px: tuple[float, float],
    side_px: float,
) -> FloorContrast:
    """``rover_id``'s marker, of colour ``color_bgr`` (its level in its plane is its chroma's length), seen at image
    pixel ``uv_px`` about ``side_px`` across, against the empty floor ``background`` (H, W, 3 BGR): the floor's level
    is its mean plane value over a window of :data:`WINDOW_SIDES` sides (the median in the tracker; the mean of a box
    filter is the same on a floor and costs one pass), at the marker's place and at the highest in view."""
    b1, b2, _ = opponent_planes(background)
    return _contrast(b1, b2, rover_id, color_bgr, uv_px, side_px)


def _contrast(
    b1: NDArray[np.float32],
    b2: NDArray[np.float32],
    rover_id: str,
    color_bgr: Sequence[int],
    uv_px: tuple[float, float],
    side_px: float,
) -> FloorContrast:
    """:func:`floor_contrast` on the empty floor's opponent chroma ``b1``, ``b2`` (computed once for every marker)."""
    c1, c2, _ = chroma_of_bgr(color_bgr)
    level = math.hypot(c1, c2)
    if level <= 0.0:
        raise ValueError(f"marker colour {tuple(color_bgr)} is grey: it has no hue")
    plane = (b1 * np.float32(c1 / level) + b2 * np.float32(c2 / level)).astype(np.float32)
    k = max(3, round(WINDOW_SIDES * side_px) | 1)
    floor = np.asarray(cv2.blur(plane, (k, k), borderType=cv2.BORDER_REFLECT), np.float32)
    h, w = floor.shape
    u, v = min(w - 1, max(0, round(uv_px[0]))), min(h - 1, max(0, round(uv_px[1])))
    wv, wu = np.unravel_index(int(np.argmax(floor)), floor.shape)
    worst = (float(wu), float(wv))
    return FloorContrast(rover_id, _ratio(level, float(floor[v, u])), _ratio(level, float(floor[wv, wu])), worst)


def _ratio(level: float, floor: float) -> float:
    """The marker's level over the floor's; inf where the tracker counts the floor as 0 (a grey floor's tint)."""
    return math.inf if floor <= SURROUND_IGNORED * level else level / floor


def floor_warnings(
    background: U8,
    markers: Sequence[tuple[str, Sequence[int], tuple[float, float], float]],
    calibration: PlaneMapping,
) -> list[str]:
    """:func:`contrast_warnings` for ``markers`` (``(rover_id, color_bgr, uv_px, side_px)`` each) against the empty
    floor ``background``, the most marker-like places named on the floor through ``calibration``."""
    b1, b2, _ = opponent_planes(background)
    contrasts = [_contrast(b1, b2, *m) for m in markers]
    where: list[tuple[float, float] | None] = []
    for c in contrasts:
        xy = calibration.pixel_to_world(np.array([c.worst_uv_px], np.float64))[0]
        where.append((float(xy[0]), float(xy[1])) if np.all(np.isfinite(xy)) else None)
    return contrast_warnings(contrasts, where)


def contrast_warnings(contrasts: Sequence[FloorContrast], where_cm: Sequence[tuple[float, float] | None]) -> list[str]:
    """A line for each marker that the floor defeats (under :data:`STANDOUT`) or nearly (under :data:`MARGINAL`),
    here or at its most marker-like place (``where_cm``: that place on the floor, None if off it)."""
    lines = []
    for c, where in zip(contrasts, where_cm, strict=True):
        low = min(c.here, c.worst)
        if low >= MARGINAL:
            continue
        place = (
            "where it stands"
            if c.here <= c.worst
            else (
                f"at ({where[0]:.0f}, {where[1]:.0f}) cm on the floor" if where is not None else "in part of the view"
            )
        )
        verdict = (
            "the tracker will not find it there"
            if low < STANDOUT
            else "it is found only while its light and size hold (farther from the camera, or in shade, it may not be)"
        )
        lines.append(
            f"{c.rover_id} stands out only {low:.1f} times from the floor in its colour, {place} (the tracker needs "
            f"{STANDOUT:g}, {MARGINAL:g} to be safe): {verdict}; use a marker of a hue farther from the floor's"
        )
    return lines
