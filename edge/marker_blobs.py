"""Where the markers are in a frame of rovers standing on a floor whose empty image is known: the blobs colour
enrolment (``edge.enroll``) measures. Pure functions over a frame's and the empty floor's opponent planes
(``edge.floor_change.planes``).

The camera family (``edge.sim.cameras``) and real webcams make this harder than a threshold on saturation:

* a **black body**'s tint (a white balance's error, the sensor's crosstalk, the stream's chroma bled from its
  marker) is a large share of its few levels of brightness. Saturation is judged against the light where a pixel
  stands: its own brightness or, if more, half the empty floor's there (:data:`LOCAL_LIGHT`);
* a **wooden floor** is itself as saturated as a pale marker (0.3): a marker's pixel must also stand apart from the
  floor's colour there, and a light body over wood (which hides the floor's colour) is not a marker left in the
  background (:func:`left_behind` compares the background with the floor round it, not with the frame);
* an **automatic white balance** over a warm floor turns white bluish by 0.2-0.3 of its brightness: a white or light
  grey body round its marker joined it in one blob two to three times the marker's area. Each blob is cut down to
  its own colour (:func:`marker_parts`) and a body's tinted parts beside their marker are dropped
  (:func:`without_rims`);
* the floor far beyond the working area is noisy: blobs there are left out when the calibration knows its area.

Over the family (``benchmarks/bench_enrolment.py``, docs/benchmarks.md "Enrolment over the camera family") the old
threshold enrolled every rover at its place in 3 of 40 eight-hue labs; these rules in 39 of 40, and 78 of 80 on
seeds held out from their tuning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.floor_change import planes
from edge.trackers.base import PlaneMapping
from edge.trackers.plane import WithWorkingArea

U8 = NDArray[np.uint8]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Planes = tuple[FloatArray, FloatArray, FloatArray]  # (c1, c2, luminance): edge.floor_change.planes

MIN_SATURATION = 0.18  # a marker's pixel: saturated and apart from the floor by this, relative to the light (coloured)
LOCAL_LIGHT = 0.5  # the light at a pixel: its own brightness, or this share of the floor's there if more
PART_SATURATION = 0.22  # a marker's part: its median pixel's (a light body's tint: 0.2-0.3; markers 0.26-1.3)
RIM_RATIO = 1.3  # a part near one this many times as saturated is that one's body (without_rims)
CORE_SHARE = 0.5  # a marker's pixel carries this share of its part's dominant chroma at least (marker_parts)
AREA_RANGE = (0.25, 1.6)  # a coloured blob's area as a share of the nominal marker's: smaller is debris, larger not
AREA_MARGIN_CM = 25.0  # a blob farther than this outside the calibration's working area is not a rover to enrol
OPEN3 = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class Blob:
    """A marker-sized blob: its pixels, its outline on the marker plane (cm) and the area inside it (cm2)."""

    mask: BoolArray
    world: FloatArray
    area_cm2: float


def relative_saturation(image: Planes, floor_lum: FloatArray) -> FloatArray:
    """Each pixel's saturation, |chroma| over the light there (:data:`LOCAL_LIGHT`)."""
    c1, c2, lum = image
    return np.asarray(np.hypot(c1, c2) / np.maximum(np.maximum(lum, LOCAL_LIGHT * floor_lum), 8.0))


def coloured(image: Planes, floor: Planes) -> BoolArray:
    """Where ``image`` shows a marker's colour over ``floor`` (the same place empty): saturated, and apart from the
    floor's own colour, both by :data:`MIN_SATURATION` relative to the light there."""
    (c1, c2, lum), (g1, g2, glum) = image, floor
    light = np.maximum(np.maximum(lum, LOCAL_LIGHT * glum), 8.0)
    glight = np.maximum(glum, 8.0)
    apart = np.hypot(c1 / light - g1 / glight, c2 / light - g2 / glight)
    return np.asarray((relative_saturation(image, glum) >= MIN_SATURATION) & (apart >= MIN_SATURATION))


def floor_around(background: U8) -> U8:
    """The empty floor's colour round each pixel: the median over a window wider than a marker (at a quarter of
    the resolution), so a marker left on the floor differs from it and the floor's own pattern does not."""
    h, w = background.shape[:2]
    small = cv2.resize(background, (max(1, w // 4), max(1, h // 4)), interpolation=cv2.INTER_AREA)
    return np.asarray(cv2.resize(cv2.medianBlur(small, 31), (w, h), interpolation=cv2.INTER_LINEAR))


def components(mask: BoolArray) -> list[BoolArray]:
    """The 8-connected parts of ``mask``."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    return [labels == k for k in range(1, n)]


def world_outline(mask: BoolArray, calibration: PlaneMapping) -> FloatArray | None:
    """(K, 2) the blob's outline on the marker plane, cm; None when it leaves the plane (beyond the horizon)."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    outline = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    world = calibration.pixel_to_world(outline)
    return None if not np.all(np.isfinite(world)) else world


def marker_parts(mask: BoolArray, c1: FloatArray, c2: FloatArray) -> list[BoolArray]:
    """Each connected part of ``mask`` cut down to its own colour: the pixels whose chroma along the part's
    dominant chroma (the median over its most saturated quarter) is at least :data:`CORE_SHARE` of it, the pixels
    the marker covers more than half of; gaps of a pixel closed (a glare across a marker nearly side to side)."""
    parts = []
    for part in components(mask):
        a, b = c1[part], c2[part]
        strength = np.hypot(a, b)
        top = strength >= np.percentile(strength, 75)
        direction = np.array([np.median(a[top]), np.median(b[top])])
        full = float(np.hypot(*direction))
        if full <= 0.0:
            continue
        core = np.zeros_like(part)
        core[part] = (a * direction[0] + b * direction[1]) / full**2 >= CORE_SHARE
        parts += components(cv2.morphologyEx(core.astype(np.uint8), cv2.MORPH_CLOSE, OPEN3).astype(bool))
    return parts


def without_rims(parts: list[BoolArray], saturation: FloatArray) -> list[BoolArray]:
    """``parts`` with a median saturation of :data:`PART_SATURATION` at least, and none within half a part's size
    of that part if it is :data:`RIM_RATIO` times as saturated or more: a light body's tinted sides and top (median
    0.2-0.3) beside its marker (0.26-1.3), apart from it by the top's margin. Rovers to enrol stand apart by more
    than half a marker. The parts dropped are not listed: a marker this drops shows as one missing (a count of
    markers short of the ids), and enrolling again with the rovers farther apart tells which."""
    levels = [float(np.median(saturation[p])) for p in parts]
    reach = [max(2, round(0.5 * math.sqrt(float(p.sum())))) for p in parts]
    grown = [
        cv2.dilate(p.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)).astype(bool)
        for p, r in zip(parts, reach, strict=True)
    ]
    return [
        p
        for i, p in enumerate(parts)
        if levels[i] >= PART_SATURATION
        and not any(j != i and levels[j] >= RIM_RATIO * levels[i] and (grown[j] & p).any() for j in range(len(parts)))
    ]


def sized_blobs(mask: BoolArray, calibration: PlaneMapping, nominal_cm2: float) -> tuple[list[Blob], list[str]]:
    """Marker-sized blobs of ``mask`` in the working area (when ``calibration`` knows it, :data:`AREA_MARGIN_CM`
    round it), and a line for each other blob of colour."""
    found, ignored = [], []
    lo, hi = AREA_RANGE
    inf = float("inf")
    x0, y0, x1, y1 = calibration.area_cm if isinstance(calibration, WithWorkingArea) else (-inf, -inf, inf, inf)
    for part in components(mask):
        if part.sum() < 6:
            continue
        world = world_outline(part, calibration)
        if world is None:
            continue
        area = float(cv2.contourArea(world.astype(np.float32)))
        x, y = world.mean(axis=0)
        if area < 0.05 * nominal_cm2:
            continue
        m = AREA_MARGIN_CM
        if not (x0 - m <= x <= x1 + m and y0 - m <= y <= y1 + m):
            ignored.append(f"a coloured blob at ({x:.0f}, {y:.0f}) cm: outside the working area")
        elif lo * nominal_cm2 <= area <= hi * nominal_cm2:
            found.append(Blob(part, world, area))
        else:
            size = "too small" if area < lo * nominal_cm2 else "too large"
            ignored.append(
                f"a coloured blob of {area:.0f} cm2 at ({x:.0f}, {y:.0f}) cm: {size} for a marker of "
                f"{nominal_cm2:.0f} cm2"
            )
    return found, ignored


def marker_blobs(
    frame: Planes,
    background: Planes,
    changed: BoolArray,
    saturation: FloatArray,
    calibration: PlaneMapping,
    nominal_cm2: float,
) -> tuple[list[Blob], list[str]]:
    """The markers in ``frame`` over the empty floor ``background`` (``changed``: where they differ,
    ``edge.floor_change.changed_from``; ``saturation``: :func:`relative_saturation`): its coloured pixels, each
    part cut down to its own colour, bodies' rims dropped, the marker-sized ones kept; and a line for each other
    blob of colour."""
    c1, c2, _ = frame
    opened = cv2.morphologyEx((changed & coloured(frame, background)).astype(np.uint8), cv2.MORPH_OPEN, OPEN3)
    mask = np.asarray(cv2.morphologyEx(opened, cv2.MORPH_CLOSE, OPEN3), dtype=bool)  # a glare across a marker
    cores = np.zeros_like(changed)
    for part in without_rims(marker_parts(mask, c1, c2), saturation):
        cores |= part
    return sized_blobs(cores, calibration, nominal_cm2)


def left_behind(
    frame: Planes,
    background: Planes,
    background_image: U8,
    changed: BoolArray,
    calibration: PlaneMapping,
    nominal_cm2: float,
) -> tuple[float, float] | None:
    """Where (cm) a marker-sized blob of colour stands in the empty floor's image (``background_image``, its
    planes ``background``) but not in ``frame``: coloured against the floor round it (:func:`floor_around`), and
    the frame there not (a wooden floor, where the marker stood, is coloured against the marker). None: nowhere."""
    around = planes(floor_around(background_image))
    mask = changed & coloured(background, around) & ~coloured(frame, around)
    blobs, _ = sized_blobs(
        cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, OPEN3).astype(bool), calibration, nominal_cm2
    )
    if not blobs:
        return None
    x, y = blobs[0].world.mean(axis=0)
    return float(x), float(y)
