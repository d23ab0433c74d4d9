"""One rover's search window, prepared once per frame for its tracker (the per-window stages before it runs).

The pipeline (``edge.pipeline``) places the window where the rover's filter predicts it; :func:`prepare_window`
sees it under the configured white (``edge.white``), splits it into colour planes and hue classes, and keeps the
background reference's crop for background subtraction (eq. 2) when a choice needs it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from edge.background import BackgroundModel, subtract_background
from edge.segmentation import (
    F32,
    U8,
    BoolArray,
    ColorModel,
    linear_bgr,
    opponent_planes,
)
from edge.trackers.plane import LocalPlaneMap, PlaneGrid, PlaneMapping
from edge.tracking import StageClock
from edge.white import LocalWhite

WINDOW_PAD_PX = 6  # room for the marker's edge band (2 px ring + 3 px outer band) where a centimetre is few pixels
OTHER_MARKER = 0.4  # a pixel of another rover's hue is its marker's at this share of that marker's saturation or more


@dataclass(kw_only=True)
class Window:
    """One rover's full-resolution search window, prepared once by the pipeline for the tracker.

    ``box``: ``(x0, y0, x1, y1)`` in the image (exclusive ends). ``bgr``: the (h, w, 3) crop (a view of the
    frame). ``c1``, ``c2``, ``lum``: opponent chroma and luminance (float32). ``classes``: (h, w) int16 rover
    index per pixel from the hue table (-1: none). ``plane``: the rover's colour plane (chroma projected on its
    hue). ``reference``: the background reference's crop (None where it is nowhere valid yet), compared by
    :meth:`foreground_fraction` (eq. 2) only when a choice needs it. ``reference_valid``: where the background
    reference is trustworthy. ``grid``: the pixel-to-plane mapping;
    ``local``: its homography at the window's centre (for point queries). ``image_size``: (w, h) of the frame.
    ``predicted_uv``: where the filter expects the marker centre, in image pixels. ``raw``: the crop as the camera
    gave it (``bgr`` is seen under the configured white, ``edge.white``; the reference is compared with ``raw``).
    ``hue``: the rover's hue direction in the chroma plane (unit ``(c1, c2)``), the one ``plane`` projects on.
    ``saturations``: (N,) each rover's marker's relative saturation (``|c| / lum``; ``ColorModel.saturations``).
    ``gains``: the per-channel gains ``bgr`` was seen under (``LocalWhite.gains``; None: ``bgr`` is ``raw``).
    """

    box: tuple[int, int, int, int]
    bgr: U8
    c1: F32
    c2: F32
    lum: F32
    classes: NDArray[np.int16]
    plane: F32
    hue: tuple[float, float]
    saturations: NDArray[np.float64]
    reference: U8 | None
    reference_valid: BoolArray
    grid: PlaneGrid
    local: LocalPlaneMap
    predicted_uv: tuple[float, float]
    image_size: tuple[int, int]
    background_threshold: float = 0.2
    raw: U8 | None = None
    gains: NDArray[np.float64] | None = None
    _others: dict[int, BoolArray | None] = field(default_factory=dict, repr=False)

    @property
    def offset(self) -> tuple[int, int]:
        return self.box[0], self.box[1]

    def others(self, index: int) -> BoolArray | None:
        """The pixels of other rovers' hues than rover ``index``'s (None where there are none), computed once for the
        window's stages."""
        if index not in self._others:
            others = (self.classes >= 0) & (self.classes != index)
            self._others[index] = others if np.count_nonzero(others) else None
        return self._others[index]

    def other_markers(self, index: int, box: tuple[slice, slice]) -> BoolArray | None:
        """The pixels of other rovers' markers within ``box`` (rows, columns; None where there are none there): of
        :meth:`others`, those saturated as a marker is (:data:`OTHER_MARKER` of that marker's ``saturations``) or
        more. ``box``: the part a stage reads (``edge.coverage.reach_box``); the
        rest of the window is left unmarked.

        The hue classes take far paler pixels (``min_saturation_fraction``): a white body in the shade of a sunlit
        room, lit by the sky, is pale blue, a fifth to a quarter of a blue marker's saturation, and of the blue
        rover's class. It is no marker, and is what the red marker's edge mixes with (``edge.coverage``): left out
        of its surround, the red marker's area fell by a fifth (docs/benchmarks.md, "A pale body of another rover's
        hue")."""
        others = self.others(index)
        if others is None:
            return None
        part = others[box]
        if not np.count_nonzero(part):
            return None
        c1, c2, lum = self.c1[box], self.c2[box], self.lum[box]
        like = (OTHER_MARKER * self.saturations.take(self.classes[box], mode="clip")).astype(np.float32)
        need = like * np.maximum(lum, np.float32(4.0))
        strong = part & (np.sqrt(c1 * c1 + c2 * c2) >= need)
        if not np.count_nonzero(strong):
            return None
        markers = np.zeros_like(others)
        markers[box] = strong
        return markers

    @cached_property
    def floor_plane(self) -> F32 | None:
        """The background reference's crop in the rover's colour plane, seen under the window's white (``gains``):
        the floor's own level at every pixel where ``reference_valid`` (None without a reference)."""
        if self.reference is None:
            return None
        seen = self.reference if self.gains is None else LocalWhite.correct(self.reference, self.gains)
        c1, c2, _ = opponent_planes(seen)
        d1, d2 = self.hue
        return np.asarray(c1 * np.float32(d1) + c2 * np.float32(d2), np.float32)

    @cached_property
    def linear(self) -> F32:
        """``bgr`` in linear light (``edge.segmentation.linear_bgr``), computed once for the window's stages."""
        return linear_bgr(self.bgr)

    def foreground_fraction(self, mask: BoolArray) -> float:
        """Share of the ``mask`` pixels that differ from a valid background reference (eq. 2 in normalised
        chroma); 1 where there is no valid reference to compare with."""
        if self.reference is None:
            return 1.0
        sel = mask & self.reference_valid
        n = int(sel.sum())
        if n == 0:
            return 1.0
        seen = self.bgr if self.raw is None else self.raw
        fg = subtract_background(seen[sel][None], self.reference[sel][None], self.background_threshold)
        return float(fg.sum()) / n


def prepare_window(
    image: NDArray[np.uint8],
    box: tuple[int, int, int, int],
    *,
    rover_index: int,
    predicted_uv: tuple[float, float],
    colors: ColorModel,
    maps: PlaneGrid,
    background: BackgroundModel,
    background_threshold: float,
    clock: StageClock,
    white: LocalWhite | None = None,
    others: Sequence[tuple[int, int, int, int]] = (),
    unseen_since: int | None = None,
) -> Window | None:
    """The per-window stages before a tracker runs: the window seen under the configured white (``edge.white``),
    colour planes, hue classes, background subtraction (eq. 2). ``box``: the window in the image; ``rover_index``:
    whose colour plane to extract; ``predicted_uv``: where the filter expects the marker (image pixels); ``others``:
    the other tracked rovers' boxes (not floor, for the local light); ``unseen_since``: the refresh since which the
    rover was not tracked (``BackgroundModel.valid_since``: the reference copied since may show it), None while
    it is."""
    x0, y0, x1, y1 = box
    t0 = time.perf_counter()
    raw = image[y0:y1, x0:x1]
    valid = background.valid[y0:y1, x0:x1] if unseen_since is None else background.valid_since(box, unseen_since)
    reference = background.reference[y0:y1, x0:x1] if np.count_nonzero(valid) else None
    gains = None if white is None else white.gains(box, raw, reference, valid, others)
    crop = raw if gains is None else LocalWhite.correct(raw, gains)
    c1, c2, lum = opponent_planes(crop)  # RGB colour planes extraction, generalised to N colours
    classes = colors.classify(c1, c2, lum)
    plane = colors.plane(rover_index, c1, c2)
    t1 = time.perf_counter()
    clock.add("planes", t1 - t0)
    local = maps.at(0.5 * (x0 + x1), 0.5 * (y0 + y1))
    clock.add("calibration", time.perf_counter() - t1)
    if local is None:
        return None
    return Window(
        box=box,
        bgr=crop,
        c1=c1,
        c2=c2,
        lum=lum,
        classes=classes,
        plane=plane,
        hue=(float(colors.directions[rover_index][0]), float(colors.directions[rover_index][1])),
        saturations=colors.saturations,
        reference=reference,
        reference_valid=valid,
        grid=maps,
        local=local,
        predicted_uv=predicted_uv,
        image_size=(image.shape[1], image.shape[0]),
        background_threshold=background_threshold,
        raw=raw,
        gains=gains,
    )


def window_box(
    maps: PlaneGrid,
    calibration: PlaneMapping,
    xy_cm: tuple[float, float],
    radius_cm: float,
    shape: tuple[int, ...],
    hint_uv: tuple[float, float] | None,
) -> tuple[tuple[int, int, int, int] | None, tuple[float, float]]:
    """Pixel box around the world circle ``xy_cm``/``radius_cm`` on the plane, clipped to the image, and the
    circle centre's pixel.

    Projected through the local plane map near ``hint_uv`` (the rover's last image position) instead of the
    full calibration: a few multiplications instead of a lens model per point.
    """
    if hint_uv is None:
        centre = np.asarray(calibration.world_to_pixel(np.array([xy_cm])), dtype=np.float64)[0]
        hint_uv = (float(centre[0]), float(centre[1]))
    local = maps.at(*hint_uv)
    if local is None:
        return None, (math.nan, math.nan)
    u, v, su, sv = local.pixel_of(*xy_cm)
    better = maps.at(u, v)
    if better is None:
        return None, (u, v)
    if better is not local:  # the circle's centre lies in another tile: map it through that one
        u, v, su, sv = better.pixel_of(*xy_cm)
    # The image of the circle is an ellipse whose bounding box, to first order, is this (the margin covers
    # the perspective's second order).
    h, w = shape[:2]
    pad = WINDOW_PAD_PX
    x0 = max(0, math.floor(u - radius_cm * su) - pad)
    y0 = max(0, math.floor(v - radius_cm * sv) - pad)
    x1 = min(w, math.ceil(u + radius_cm * su) + pad + 1)
    y1 = min(h, math.ceil(v + radius_cm * sv) + pad + 1)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None, (u, v)
    return (x0, y0, x1, y1), (u, v)
