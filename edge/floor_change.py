"""What differs from the empty floor: the test colour enrolment finds markers with, and the check that a background
model has not learned a rover into its floor.

A pixel differs from the floor when its chroma relative to its luminance moved by more than :data:`CHROMA_CHANGE`, or
its luminance by a quarter (20 levels at least): a marker, a body, a shadow. ``edge.enroll`` looks for markers
there. Enrolling against the tracker's background model (the dashboard) needs one more check: the model learns what
the tracker does not track into its floor, and a rover that stood untracked in one place for a while is then part of
the model where it stands. Its marker does not differ from that floor, :func:`edge.enroll.enroll` does not find it,
and the rover would be left out of the enrolment (:func:`in_background`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from edge.trackers.base import PlaneMapping

U8 = NDArray[np.uint8]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Planes = tuple[FloatArray, FloatArray, FloatArray]

CHROMA_CHANGE = 0.12  # normalised chroma difference from the empty floor that counts as "something is there"
IN_BACKGROUND_SHARE = 0.5  # in_background: a marker's middle differing from the background less than this is in it


def planes(image: U8) -> Planes:
    """The opponent chroma planes and the luminance of a BGR image (float64)."""
    f = image.astype(np.float64)
    b, g, r = f[..., 0], f[..., 1], f[..., 2]
    return (r - g) / math.sqrt(2.0), (r + g - 2.0 * b) / math.sqrt(6.0), (b + g + r) / 3.0


def changed_from(now: Planes, then: Planes) -> BoolArray:
    """Where the image whose :func:`planes` are ``now`` differs from the floor whose planes are ``then``."""
    (f1, f2, flum), (b1, b2, blum) = now, then
    chroma = np.hypot(
        f1 / np.maximum(flum, 8.0) - b1 / np.maximum(blum, 8.0),
        f2 / np.maximum(flum, 8.0) - b2 / np.maximum(blum, 8.0),
    )
    return np.asarray((chroma > CHROMA_CHANGE) | (np.abs(flum - blum) > np.maximum(20.0, 0.25 * blum)))


def differs(frame: U8, background: U8) -> BoolArray:
    """Where ``frame`` differs from ``background`` (same shape, BGR)."""
    return changed_from(planes(frame), planes(background))


def in_background(
    frame: U8, background: U8, calibration: PlaneMapping, places: Sequence[tuple[float, float]], half_cm: float
) -> int | None:
    """The index of the first of ``places`` (marker centres on the plane, cm) whose middle (``half_cm`` round it) in
    ``frame`` mostly does not differ from ``background`` (under :data:`IN_BACKGROUND_SHARE` of it does): a marker the
    background has too, where it stands. None when every one differs (or lies off the image)."""
    h, w = frame.shape[:2]
    for k, (x, y) in enumerate(places):
        uv = calibration.world_to_pixel(np.array([[x, y], [x + half_cm, y]], np.float64))
        if not np.all(np.isfinite(uv)):
            continue
        r = max(2, round(float(np.hypot(*(uv[1] - uv[0])))))
        u, v = round(float(uv[0][0])), round(float(uv[0][1]))
        box = (slice(max(0, v - r), min(h, v + r + 1)), slice(max(0, u - r), min(w, u + r + 1)))
        if frame[box].size and float(np.mean(differs(frame[box], background[box]))) < IN_BACKGROUND_SHARE:
            return k
    return None
