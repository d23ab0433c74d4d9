"""The shaded part of a marker in two lights that its threshold cut away (``edge.trackers.base.threshold_marker``).

Where the shadow of a window's bar or frame crosses a marker in a sunlit patch, its part in the shade is three to
six times darker (linear light) than its part in the sun. Thresholded at the sunlit level, the shaded part falls
below the bound and the blob lacks it: a corner or an end missing, the blob lopsided and too small, refused as a
marker partly hidden (the family's sun clips on wood: a red marker turned 45 degrees with a corner in the shade,
refused for 7 frames running; ``docs/benchmarks.md``, "The shaded part of a marker"). The two-lights test that
would have thresholded it at the light where each part stands looked at the blob's interior only, all of it sunlit.

A shaded part keeps the marker's colour: its chroma lies along the marker's hue and its relative saturation
(chroma over luminance, in the encoded values the window holds) is the marker's, at a fraction of its
brightness. :func:`shaded_part` finds such pixels joined to the mask. The rover's body beside the marker can look
the same in a coarse stream (the marker's chroma spread onto a dark body: its hue, low brightness): that is told
apart by size (a whole side of the body, beyond what is missing from the marker's expected area), and whether the
pixels put the marker in two lights at all is the caller's test (its interior, eroded: a rim of 1-2 px is not).
"""

from __future__ import annotations

import math

import numpy as np

from edge.coverage import TWO_LIGHTS, light_ratio
from edge.segmentation import F32, BoolArray, dilate, erode, reconstruct

SHADE_HUE_DEG = 25.0  # a shaded pixel's chroma within this angle of the marker's hue
SHADE_SATURATION = (0.6, 1.6)  # ... its relative saturation within these factors of the marker's
SHADE_LEVEL = (0.25, 0.85)  # ... its luminance within these fractions of the marker's
SHADE_MISSING = 0.97  # looked for only when the mask has fewer pixels than this share of the marker's expected ones
SHADE_FILL = 1.2  # none taken when the mask with them would have more than this share of the expected pixels


def shaded_part(
    c1: F32, c2: F32, lum: F32, candidates: BoolArray, mask: BoolArray, marker_px: float
) -> BoolArray | None:
    """(h, w) the ``candidates`` (the rover's hue class) outside ``mask`` that look like the marker in a shade and
    are joined to it, within half the marker's expected size (``marker_px``, in pixels) of it; None when the mask is
    not short of the marker's size (:data:`SHADE_MISSING`), when there are none, or when they would make it too large
    (:data:`SHADE_FILL`: the body's side). ``c1``, ``c2``, ``lum``: the window's opponent chroma and luminance."""
    held = int(np.count_nonzero(mask))
    if held >= SHADE_MISSING * marker_px:
        return None
    inner = erode(mask, 1)
    if np.count_nonzero(inner) < 8:
        return None
    h1, h2 = float(np.mean(c1[inner])), float(np.mean(c2[inner]))
    norm = math.hypot(h1, h2)
    if norm <= 1e-6:
        return None
    chroma = np.hypot(c1, c2)
    saturation = chroma / np.maximum(lum, np.float32(1.0))
    ref_saturation, ref_level = float(np.median(saturation[inner])), float(np.median(lum[inner]))
    reach = max(2, int(0.5 * math.sqrt(max(marker_px, 1.0))))
    pick = (
        candidates
        & dilate(mask, reach)
        & ~mask
        & (
            (c1 * np.float32(h1 / norm) + c2 * np.float32(h2 / norm))
            >= np.float32(math.cos(math.radians(SHADE_HUE_DEG))) * chroma
        )
        & (saturation >= np.float32(SHADE_SATURATION[0] * ref_saturation))
        & (saturation <= np.float32(SHADE_SATURATION[1] * ref_saturation))
        & (lum > np.float32(SHADE_LEVEL[0] * ref_level))
        & (lum < np.float32(SHADE_LEVEL[1] * ref_level))
    )
    if not np.count_nonzero(pick):
        return None
    part = reconstruct(dilate(mask, 1), pick)  # those joined to the mask
    if not np.count_nonzero(part):
        return None
    if held + int(np.count_nonzero(part)) > SHADE_FILL * marker_px:
        return None  # more than the marker lacks: the body's side with the marker's chroma spread onto it
    return part


def in_two_lights(
    c1: F32, c2: F32, lum: F32, candidates: BoolArray, mask: BoolArray, marker_px: float, gap: int
) -> BoolArray | None:
    """The mask of a marker in two lights, None under one light: its interior (edges left out, its gaps of up to
    ``2 gap`` px closed first: eroding the closed mask twice is eroding its dilation twice more) spans
    :data:`edge.coverage.TWO_LIGHTS` in brightness, or does with the shaded part the threshold cut away
    (:func:`shaded_part`; the mask is then returned with it). A mask already in two lights is returned as it is."""

    def spans(m: BoolArray) -> bool:
        return light_ratio(lum[erode(dilate(m, gap), gap + 2)], encoded=True) >= TWO_LIGHTS

    if spans(mask):
        return mask
    part = shaded_part(c1, c2, lum, candidates, mask, marker_px)
    if part is None:
        return None
    joined = mask | part
    return joined if spans(joined) else None
