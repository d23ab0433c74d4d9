"""What every tracker shares: what it is given (a :class:`Window`, a :class:`RoverModel`), what it returns (a
:class:`Measurement`), and the stages the binary trackers have in common.

A tracker here measures ONE rover in a small full-resolution window around where the rover is predicted to be.
The pipeline (``edge.pipeline``) prepares the window once (``edge.trackers.window``) and the tracker turns it into
a :class:`Measurement` in world centimetres, the marker's area centroid on the plane (``edge.trackers.plane``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from edge.background import subtract_background
from edge.coverage import (
    LOCAL_LIGHT_PX,
    coverage_weights,
    local_mean,
    marker_level,
    reach_box,
)
from edge.segmentation import F32, BoolArray, ThresholdInterval, auto_threshold, close, erode, threshold
from edge.shade import in_two_lights
from edge.trackers.plane import (
    CameraPlaneMapping,
    FloatArray,
    LocalPlaneMap,
    PlaneGrid,
    PlaneMapping,
    WorldBlob,
    shape_elongation,
    world_blob,
)
from edge.trackers.window import Window
from edge.tracking import NullClock, StageClock

__all__ = [
    "CameraPlaneMapping",
    "FloatArray",
    "LocalPlaneMap",
    "Measurement",
    "NullClock",
    "PlaneGrid",
    "PlaneMapping",
    "RoverModel",
    "StageClock",
    "Window",
    "WindowTracker",
    "WorldBlob",
    "area_quality",
    "make_measurement",
    "measure_core",
    "measurement_covariance",
    "threshold_marker",
    "world_blob",
]

SHADE_GAP_PX = 4  # the widest gap in a marker's mask closed for the two-lights test (threshold_marker)
SURROUND_IGNORED = 0.1  # a surround this much of the marker's level in its plane counts as 0 (surrounded: grey floors)
# a marker is at least this many times its surround's level in its plane (surrounded); the brightest planks of the
# simulator's wood reach about 1.4 times its median in a window, a red marker on it 1.6-2.5 times
STANDOUT = 1.5
# at_marker_level: the median of a marker's expected area of the brightest pixels stands this much above the window's
MARKER_STANDOUT = 2.0
ACROSS_MIN = 0.3  # across_floor: the marker's hue at least this far across the floor's (the sine: 17 deg)
GRAIN = 4.0  # clear_of_grain: a marker's level this many times the surround's grain above it, across the floor's hue
JOINED_FLOOR = 1.08  # joined_to_floor: a mask this much larger than the marker has floor in it (as JOINED_AREA)
ACROSS_SHARE = 0.1  # clear_of_grain: a marker's top across the floor's hue at least this share of its top in its plane


@dataclass(frozen=True)
class RoverModel:
    """What a tracker knows about the rover it measures (mutable state stays in the pipeline).

    ``index``: the rover's index in the colour model. ``marker_area_cm2``: expected marker area on the plane.
    ``marker_level``: the marker's current value in its colour plane (for coverage weights), or 0 if unknown."""

    index: int
    marker_area_cm2: float
    marker_level: float


@dataclass(frozen=True)
class Measurement:
    """A tracker's measurement of one rover in one frame (before filtering).

    ``xy_cm``: marker centre on the plane; ``uv_px``: coverage-weighted image centroid; ``area_cm2``: measured
    marker area on the plane; ``level``: the marker's value in its colour plane (the next frame's threshold
    reference); ``quality`` 0..1; ``axis_rad``: long-axis orientation modulo pi; ``elongation``: ratio of the
    blob's principal standard deviations on the plane (1.28 for a 21.5 x 16.8 cm rectangle);
    ``at_image_edge``: the blob touches the border of the image (the marker may be cut off); ``weights``: the
    (h, w) float32 coverage of each window pixel by the marker that the centre was taken from (None if the tracker
    has none), so a later step can re-weigh an edge it knows more about (a two-tone marker's inner edge);
    ``core_cm2``: the area on the plane of the blob's binary core (its thresholded pixels, holes filled; 0: not
    known), a second measure of its size that does not rest on the edge model; ``outlined``: the centre and axis
    come from the marker's fitted outline, whose size matched the marker's
    (``edge.trackers.refine``); ``axis_coherence``: how clearly the marker's edges showed that axis (0..1; 0: the
    blob's principal axis).
    """

    xy_cm: tuple[float, float]
    uv_px: tuple[float, float]
    area_cm2: float
    level: float
    quality: float
    axis_rad: float
    elongation: float
    at_image_edge: bool
    weights: F32 | None = field(default=None, compare=False, repr=False)
    outlined: bool = False
    axis_coherence: float = 0.0
    core_cm2: float = 0.0

    def with_axis(self, axis_rad: float, coherence: float) -> Measurement:
        """This measurement with its long axis and that axis's coherence replaced (``dataclasses.replace`` costs ten
        times more)."""
        return Measurement(
            self.xy_cm,
            self.uv_px,
            self.area_cm2,
            self.level,
            self.quality,
            axis_rad,
            self.elongation,
            self.at_image_edge,
            self.weights,
            self.outlined,
            coherence,
            self.core_cm2,
        )


def make_measurement(
    blob: WorldBlob, window: Window, core: BoolArray, level: float, quality: float, weights: F32 | None = None
) -> Measurement:
    """A :class:`Measurement` of the marker whose pixels are ``core`` in ``window`` (``weights``: the coverage the
    blob was computed from; its shape's elongation: ``edge.trackers.plane.shape_elongation``)."""
    x0, y0, x1, y1 = window.box
    w, h = window.image_size
    edge = bool(
        (x0 == 0 and core[:, 0].any())
        or (y0 == 0 and core[0, :].any())
        or (x1 == w and core[:, -1].any())
        or (y1 == h and core[-1, :].any())
    )
    return Measurement(
        (blob.x_cm, blob.y_cm),
        (blob.u_px, blob.v_px),
        blob.area_cm2,
        level,
        quality,
        blob.axis_rad,
        blob.elongation if weights is None else shape_elongation(weights, window.offset, window.grid, blob),
        edge,
        weights,
        core_cm2=int(np.count_nonzero(core)) * window.local.area_at(blob.u_px, blob.v_px),
    )


def threshold_marker(
    window: Window, rover: RoverModel, fraction: float, clock: StageClock
) -> tuple[BoolArray, BoolArray] | None:
    """Stage ``threshold`` of the binary trackers: the window's pixels of the rover's hue class (``candidates``) and
    those of them inside the automatic interval of its colour plane (``mask``); None when the window has none, or
    when nothing in it stands out from a floor of its hue class (:func:`surrounded`), in its plane or across the
    floor's hue (:func:`across_floor`, :func:`clear_of_grain`).

    A marker in two lights (the edge of a sunlit patch across it) is thresholded against its level where it stands.
    Whether it is in two lights is judged on its interior with the mask's gaps of up to :data:`SHADE_GAP_PX` closed,
    and with the shaded part the threshold cut away whole, if it did (``edge.shade``); the mask it is then given has
    the gaps closed too where that joins parts that were apart. The shaded part is darker and less saturated, and a
    camera that sharpens darkens the first rows past the light's edge further: the shaded end came apart in strips,
    the interior's erosion took them away, the test saw one light, and the blob lacked its shaded end (the family's
    sun clip with seed 16661: a green rover driving into the patch refused for 11 frames). Parts already joined are
    left as they are: something joined to the marker by a thin neck is parted off there later
    (``edge.blob_shape.marker_part``); closed, the neck would be too thick to part. Under one light nothing changes.

    The interval's top is the 90th percentile of the window's pixels of the hue class. Where a coloured floor passed
    with the marker (:func:`joined_to_floor`), it is taken over the marker's expected area of the brightest of them
    instead, when that is higher (:func:`edge.segmentation.auto_threshold`'s ``marker_px``): the floor fills most of
    such a window, and the marker, a tenth of an acquisition window, lay above the percentile. In a sunlit patch of
    wood (1.6-2 times the shaded wood's level in the red plane, a third of the window) the top was the patch's, the
    patch passed with the marker and the blob, four markers' area, was refused (the family's sun clip with seed
    16661 on wood: a red rover parked at the patch's edge unfound for its first 80 frames, 2.7 s). Whether anything
    stands out from the floor (:func:`surrounded`) is still judged on the percentile, and a mask not joined to the
    floor keeps it. Taken everywhere, the higher top cut the shaded end off a marker in two lights (its sunlit part
    is the brightest marker-sized set) and moved a tracked violet marker's centre on wood by 0.2 cm (crowd 14641).

    When nothing stands out on the percentile (a lost rover's wide window on warm wood: the planks' percentile), the
    marker's own level is tried (:func:`at_marker_level`), the mask kept to pixels that differ from the empty scene
    or stand above the floor under them (:func:`above_floor`): a far-side red marker on wood was found again across
    the wood's hue only, joined to its grain, and refused for 30 frames (occlusion 14641 on wood: 96.4 -> 98.3 %)."""
    t0 = time.perf_counter()
    candidates = window.classes == rover.index
    if not np.count_nonzero(candidates):  # quicker than any() on a window
        clock.add("threshold", time.perf_counter() - t0)
        return None
    plane = window.plane
    plain = auto_threshold(plane, candidates, fraction)
    interval = surrounded(plain, plane, fraction)
    marker_top = False
    if interval is None:  # the percentile may be the floor's: the marker's own level, if it is there (see above)
        interval = at_marker_level(plane, candidates, fraction, expected_px(window, rover))
        marker_top = interval is not None
    if interval is None:  # nothing stands out from a floor of its hue class in its plane: look across the floor's hue
        across = across_floor(window.c1, window.c2, window.hue)
        if across is not None:
            plane, interval = across, surrounded(auto_threshold(across, candidates, fraction), across, fraction)
            if interval is not None and not clear_of_grain(across, interval, plain.k_max):
                interval = None
    if interval is None:
        clock.add("threshold", time.perf_counter() - t0)
        return None
    mask = candidates & threshold(plane, interval)
    # a coloured floor's level was taken from the window's median and the floor joined the marker: the floor's own
    above = above_floor(window, interval.k_max, fraction) if marker_top else None
    if plane is window.plane and not marker_top and interval is not plain and joined_to_floor(window, rover, mask):
        # the percentile was the floor's: the top over the marker's expected area of the brightest (see above)
        top = auto_threshold(plane, candidates, fraction, marker_px=expected_px(window, rover))
        if top.k_max > interval.k_max and (higher := surrounded(top, plane, fraction)) is not None:
            interval = higher
            mask = candidates & threshold(plane, interval)
        above = above_floor(window, interval.k_max, fraction)
    mask = mask if above is None else mask & above
    gap = SHADE_GAP_PX // 2
    lit = in_two_lights(window.c1, window.c2, window.lum, candidates, mask, expected_px(window, rover), gap)
    if lit is not None:  # a marker in two lights (edge.coverage): the threshold follows its level where it stands
        mask = lit
        inner = erode(mask, 1)
        mean = float(np.mean(plane[inner])) if np.count_nonzero(inner) else 0.0
        if mean > 0.0:
            here = local_mean(plane, inner, LOCAL_LIGHT_PX)  # the marker's level where it stands
            mask = candidates & (plane >= np.float32(interval.k_min / mean) * here)
            closed = close(mask, gap)
            if _parts(closed) < _parts(mask):  # a shaded end apart from the rest: joined (a neck: left alone)
                mask = closed
            if above is not None:
                mask &= above
    clock.add("threshold", time.perf_counter() - t0)
    return candidates, mask


def surrounded(interval: ThresholdInterval, plane: F32, fraction: float) -> ThresholdInterval | None:
    """``interval`` with its lower bound ``fraction`` of the way from the surround's level to the marker's, not from
    0: a pixel half covered by the marker shows the mean of the two in its plane. None when nothing stands out from
    the surround: the marker's level less than :data:`STANDOUT` times the surround's.

    The surround's level is the window's median plane value (the floor fills most of a window) less
    :data:`SURROUND_IGNORED` of the marker's, 0 at least: on grey floors, whose plane is 0 give or take the light's
    tint, nothing changes. A warm wooden floor's plane is about half a red marker's: with the bound at half the
    marker's, the floor passed with the marker, the blob joined it and was refused as too large (the red rover found
    in 30-94 % of its frames on 8 of 18 family runs on wood, docs/benchmarks.md, "Floors of other materials"). In a
    window of wood alone the interval's top is the wood's own brightest planks, and the bound halfway to them let
    plank-sized patches through as markers (a red rover hidden by a person was "found" 90-240 cm away)."""
    median = sampled_median(plane)
    if median <= SURROUND_IGNORED * interval.k_max:
        return interval
    if interval.k_max < STANDOUT * median:
        return None
    level = median - SURROUND_IGNORED * interval.k_max
    return ThresholdInterval(level + fraction * (interval.k_max - level), interval.k_max)


def at_marker_level(plane: F32, candidates: BoolArray, fraction: float, marker_px: float) -> ThresholdInterval | None:
    """The interval from the median of the ``marker_px`` brightest ``candidates`` (the marker's expected area in
    pixels): the marker's own level where it is a small share of a window of a floor of its hue class
    (:func:`threshold_marker`). None unless that level stands :data:`MARKER_STANDOUT` times the window's median:
    on the simulator's warm wood, windows of wood alone 1.11-1.55 times, a far-side red marker 2.3-2.6 times."""
    if marker_px <= 0.0:
        return None
    top = auto_threshold(plane, candidates, fraction, percentile=50.0, marker_px=marker_px)
    if top.k_max < MARKER_STANDOUT * sampled_median(plane):
        return None
    return surrounded(top, plane, fraction)


def joined_to_floor(window: Window, rover: RoverModel, mask: BoolArray) -> bool:
    """Does ``mask`` hold more than :data:`JOINED_FLOOR` times the marker's expected pixels where it is predicted
    (the floor passed with the marker)?"""
    marker_px = expected_px(window, rover)
    return marker_px > 0.0 and int(np.count_nonzero(mask)) > JOINED_FLOOR * marker_px


def expected_px(window: Window, rover: RoverModel) -> float:
    """The rover's marker's expected area in pixels where the window predicts it (0 where the plane has no area)."""
    px = window.local.area_at(*window.predicted_uv)
    return rover.marker_area_cm2 / px if px > 0.0 else 0.0


def above_floor(window: Window, k_max: float, fraction: float) -> BoolArray | None:
    """The pixels that are not the empty scene, or stand ``fraction`` of the way from the floor's own level under
    them to the marker's ``k_max``: the background model's reference, where it is valid and the pixel shows it
    (eq. 2), in the marker's plane less :data:`SURROUND_IGNORED` of ``k_max`` (as :func:`surrounded` takes the
    window's median). None without a reference.

    A warm floor in two lights has two levels, and the window's median is the larger part's. Beside a red marker in
    the shade a sunlit patch of wood was above the bound taken from the shaded wood, passed with the marker, and the
    blob, 2-3 times the marker's area, was refused (the family's sun clip with seed 16661 on wood: the red rover
    missing for 33 frames running). The reference knows the sunlit wood's own level. Only where the pixel shows the
    empty scene: round a marker the image shows the rover's body, and the reference the floor the body now hides.
    Taken only where the floor joined the marker (:func:`joined_to_floor`): elsewhere the median's bound is kept,
    and a marker's measured area with it (docs/benchmarks.md, "The floor's own level under each pixel")."""
    floor = window.floor_plane
    if floor is None or window.reference is None:
        return None
    top = np.float32(k_max)
    level = np.maximum(floor - np.float32(SURROUND_IGNORED) * top, np.float32(0.0))
    bound = level + np.float32(fraction) * (top - level)
    seen = window.bgr if window.raw is None else window.raw
    changed = subtract_background(seen, window.reference, window.background_threshold)
    return np.asarray((window.plane >= bound) | changed | ~window.reference_valid)


def across_floor(c1: F32, c2: F32, hue: tuple[float, float]) -> F32 | None:
    """The chroma ``c1``, ``c2`` along the part of the marker's hue direction ``hue`` that lies across the floor's:
    the floor (the median chroma, every 4th row) 0 in it give or take its grain, the marker its chroma times the
    sine of the angle between the two hues. None when the floor has no hue or the two are less than
    ``asin(ACROSS_MIN)`` apart.

    A far-side red marker on warm wood under a warm white balance stood only 1.2 times the wood's level in its own
    plane (occlusion 1000 on wood, frames 279-337, missing); the wood's hue is some 25 deg from red's, and across
    it the marker stood 9-13 times the wood's grain."""
    f1, f2 = sampled_median(c1), sampled_median(c2)
    norm = math.hypot(f1, f2)
    if norm <= 0.0:
        return None
    f1, f2 = f1 / norm, f2 / norm
    d1, d2 = hue
    along = d1 * f1 + d2 * f2
    e1, e2 = d1 - along * f1, d2 - along * f2
    size = math.hypot(e1, e2)
    if size < ACROSS_MIN:
        return None
    return np.asarray(c1 * np.float32(e1 / size) + c2 * np.float32(e2 / size), np.float32)


def clear_of_grain(plane: F32, interval: ThresholdInterval, level: float) -> bool:
    """Does the interval's top across the floor's hue stand :data:`GRAIN` times the plane's grain (its median
    absolute deviation, every 4th row) or more above its median, and at least :data:`ACROSS_SHARE` of ``level``
    (the interval's top in the marker's own plane)?

    Across the floor's hue the floor's level is 0 and only its grain is left: a window of wood alone had its top
    1.5-2.7 times the grain above the median (once 5.3, a marker partly hidden), a window of a marker 9-13 times.
    But where the floor's grain across is a unit of chroma or less, a faint patch of 3 is 4 times it: a patch of
    wood beyond the working area's tape was taken for a red rover 161 cm away (occlusion 14641 on wood, frame 309).
    Against the top in the marker's own plane (about 70 in both clips) the far-side red marker's top across was
    0.18-0.19 of it, windows of wood alone 0.02-0.07 (occlusion 1000 and 14641 on wood, instrumented)."""
    median = sampled_median(plane)
    grain = sampled_median(np.abs(plane - np.float32(median)))
    return interval.k_max - median >= GRAIN * grain and interval.k_max >= ACROSS_SHARE * level


def sampled_median(values: F32) -> float:
    """The median of ``values`` (H, W) from every 4th row: a floor's level in a window or a frame as well as from
    every row, at a tenth of ``np.median``'s cost (a partition, no sort)."""
    rows = values[::4].ravel()
    half = rows.size // 2
    return float(np.partition(rows, half)[half])


def _parts(mask: BoolArray) -> int:
    """How many 8-connected parts ``mask`` has."""
    return int(cv2.connectedComponents(mask.view(np.uint8), connectivity=8)[0]) - 1


def measure_core(
    window: Window,
    rover: RoverModel,
    core: BoolArray,
    candidates: BoolArray,
    mask: BoolArray,
    ring_px: int,
    clock: StageClock,
    interior: BoolArray | None = None,
    parted: BoolArray | None = None,
) -> Measurement | None:
    """Stages ``measure`` and ``calibration`` of the binary trackers: the marker whose interior is ``core`` (its
    thresholded pixels ``mask``), weighted by grey-level edge coverage (pixels of other rovers' hues left out; of the
    surround's colours only those as saturated as a marker; and ``parted``: what was parted off the marker's blob,
    ``edge.blob_shape.marker_part``) and turned into its area centroid on the world plane. Edge pixels of other hues
    that are the marker mixed with the floor beside them are the marker's (``edge.coverage.on_the_floor``), unless
    something was parted off. ``interior``: ``erode(core, 1)`` when the caller has it."""
    t0 = time.perf_counter()
    if interior is None:  # for both: the marker's level and its pure colour are taken inside its edge
        interior = erode(core, 1)
    level = marker_level(window.plane, core, interior)
    exclude = window.others(rover.index)  # the pixels of ``~candidates`` of other rovers' hues
    box = reach_box(core, ring_px)  # ... and of those, the ones as saturated as a marker, where the unmixing reads
    apart = None if box is None else window.other_markers(rover.index, box)
    if parted is not None:
        exclude = parted if exclude is None else exclude | parted
        apart = parted if apart is None else apart | parted
    # edge pixels of other hues mixed with the floor are this marker's; not when something was parted off (of its
    # own hue, joined)
    mixes = parted is None
    weights = coverage_weights(
        window.bgr, core, ring_px, exclude=exclude, pure=mask, interior=interior, apart=apart, floor_mixes=mixes
    )
    t1 = time.perf_counter()
    clock.add("measure", t1 - t0)
    blob = world_blob(weights, window.offset, window.grid)
    clock.add("calibration", time.perf_counter() - t1)
    if blob is None:
        return None
    return make_measurement(blob, window, core, level, area_quality(blob.area_cm2, rover.marker_area_cm2), weights)


class WindowTracker(Protocol):
    """Measures one rover inside its prepared window. What it keeps between frames about a rover (mean shift's
    target model) it forgets on ``reset``; the rest of the state lives in the pipeline."""

    name: str

    def measure(self, window: Window, rover: RoverModel, clock: StageClock) -> Measurement | None: ...

    def reset(self, index: int) -> None:
        """Forget rover ``index`` (it was lost, or the pipeline starts afresh)."""
        ...


def measurement_covariance(jacobian: FloatArray, sigma_px: float, floor_cm2: float = 1e-4) -> FloatArray:
    """(2, 2) covariance on the plane of a measurement with ``sigma_px`` pixel noise: ``J J^T sigma^2`` through the
    plane mapping's Jacobian there, plus ``floor_cm2`` on its diagonal (a perfectly sharp pixel is not exact); in
    plain floats."""
    s2 = sigma_px * sigma_px
    (a, b), (c, d) = jacobian.tolist()
    xy = (a * c + b * d) * s2
    return np.array([[(a * a + b * b) * s2 + floor_cm2, xy], [xy, (c * c + d * d) * s2 + floor_cm2]])


def area_quality(area_cm2: float, expected_cm2: float) -> float:
    """1 when the measured marker area is as expected, falling as it is smaller (occluded) or larger (merged)."""
    if expected_cm2 <= 0.0:
        return 1.0
    r = area_cm2 / expected_cm2
    return float(max(0.0, min(r, 1.0 / r if r > 0 else 0.0)))
