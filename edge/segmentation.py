"""Segmentation: the paper's section IV stages, each a pure function over numpy arrays.

The paper extracts the R, G and B planes (one rover per plane), subtracts a reference frame refreshed on a timer
(eq. 2), thresholds with an interval that follows the marker's maximum, erodes, and fills holes by morphological
reconstruction (Fig. 13). Here the same stages are generalised and made lighting-robust:

* **Colour planes** for N marker colours: each pixel's chroma is its BGR vector with the grey component removed,
  written in an orthonormal opponent basis ``(c1, c2)``. A marker's *plane* is the projection of the chroma onto
  the marker's hue direction. Chroma is linear in the light (a marker pixel half covered by a dark or grey
  surround has half the projection), which gives sub-pixel *coverage* weights at the marker's edge; the hue
  angle and the relative saturation ``|c| / luminance`` do not change with the illumination level, which makes
  the marker *classification* independent of drift and flicker.
* **Background model** (eq. 2): in ``edge.background``.
* **Automatic threshold interval** (Fig. 11-12): ``k_max`` is the marker's current maximum in its plane (a
  robust high percentile) and ``k_min`` a fixed fraction of it (the paper subtracts a constant; a fraction keeps
  the interval right when the light changes by a third).
* **Erosion** and **hole filling by reconstruction** (Fig. 13) on the binary marker mask.
* **Particles** (Table II): connected components with area, holes, convex hull and bounding rectangle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
BoolArray = NDArray[np.bool_]

_INV_SQRT2 = 1.0 / math.sqrt(2.0)
_INV_SQRT6 = 1.0 / math.sqrt(6.0)
HUE_BINS = 720  # 0.5 degree resolution of the hue look-up table
NO_ROVER = -1
# BGR -> (c1, c2, luminance), the rows of :func:`opponent_planes`
_OPPONENT = np.array(
    [[0.0, -_INV_SQRT2, _INV_SQRT2], [-2.0 * _INV_SQRT6, _INV_SQRT6, _INV_SQRT6], [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0]],
    np.float32,
)


# -- linear light ------------------------------------------------------------------------------------------------
def _srgb_to_linear() -> NDArray[np.float32]:
    v = np.arange(256, dtype=np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


# 8-bit value -> linear light (0..1): webcams encode with the sRGB tone curve (or BT.709, or a power law near 2.2,
# all within a few per cent of it); light mixes linearly, 8-bit values do not.
LINEAR = _srgb_to_linear()


def linear_bgr(bgr: U8) -> F32:
    """(h, w, 3) uint8 BGR -> (h, w, 3) float32 linear light through :data:`LINEAR`."""
    return np.asarray(cv2.LUT(bgr, LINEAR), dtype=np.float32)


@lru_cache(maxsize=512)
def ramp(n: int) -> NDArray[np.float64]:
    """(n, 2) float64 columns ``1`` and ``0 .. n-1`` (read-only): ``ramp(h).T @ image @ ramp(w)`` is an (h, w)
    image's sum and first moments, ``[[sum, sum x], [sum y, sum x y]]``, in two matrix products (cv2.moments costs
    several times more on a window)."""
    out = np.column_stack([np.ones(n), np.arange(n, dtype=np.float64)])
    out.flags.writeable = False
    return out


# -- colour planes -----------------------------------------------------------------------------------------------
def chroma_of_bgr(color_bgr: Sequence[float]) -> tuple[float, float, float]:
    """``(c1, c2, luminance)`` of one BGR colour (0-255): the opponent chroma and the mean of the channels."""
    b, g, r = (float(v) for v in color_bgr)
    return (r - g) * _INV_SQRT2, (r + g - 2.0 * b) * _INV_SQRT6, (b + g + r) / 3.0


def opponent_planes(bgr: U8) -> tuple[F32, F32, F32]:
    """(H, W, 3) uint8 BGR -> chroma ``c1``, ``c2`` and luminance, each (H, W) float32.

    ``c1 = (R - G) / sqrt 2``, ``c2 = (R + G - 2B) / sqrt 6`` span the plane orthogonal to grey, so a grey or
    black surface has zero chroma whatever its brightness.
    """
    planes = cv2.transform(bgr.astype(np.float32), _OPPONENT)  # one pass over the pixels for all three
    c1, c2, lum = np.ascontiguousarray(planes.transpose(2, 0, 1))  # one copy, quicker than cv2.split's three
    return c1, c2, lum


@dataclass(frozen=True)
class ColorModel:
    """How the rovers' marker colours are told apart (built once from the configured colours).

    ``directions``: (N, 2) float32 unit hue directions in the ``(c1, c2)`` plane, one per rover.
    ``saturations``: (N,) nominal relative saturation ``|c| / luminance`` of each marker colour.
    ``hue_lut``: (HUE_BINS + 1,) int16, for each hue bin (angle 0..2pi) the index of the rover whose hue is
    nearest, or :data:`NO_ROVER` when no rover hue is within the tolerance.
    """

    directions: F32
    saturations: NDArray[np.float64]
    hue_lut: NDArray[np.int16]
    min_relative_saturation: float

    @classmethod
    def from_colors(
        cls, colors_bgr: Sequence[Sequence[float]], hue_tolerance_deg: float, min_saturation_fraction: float
    ) -> ColorModel:
        """``colors_bgr``: nominal marker colours. A pixel belongs to a rover's class when its hue is nearer to
        that rover's hue than to any other and within ``hue_tolerance_deg``; it is saturated enough when its
        relative saturation is at least ``min_saturation_fraction`` of the least saturated marker's."""
        dirs, sats, angles = [], [], []
        for color in colors_bgr:
            c1, c2, lum = chroma_of_bgr(color)
            mag = math.hypot(c1, c2)
            if mag < 1e-6:
                raise ValueError(f"marker colour {tuple(color)} is grey: it has no hue to track")
            dirs.append((c1 / mag, c2 / mag))
            sats.append(mag / max(lum, 1.0))
            angles.append(math.atan2(c2, c1))
        centres = (np.arange(HUE_BINS) + 0.5) * (2.0 * math.pi / HUE_BINS)  # hue angles 0..2pi, as cv2.phase gives
        lut = np.full(HUE_BINS + 1, NO_ROVER, dtype=np.int16)  # one extra bin: cv2.phase may return exactly 2pi
        if angles:
            diff = np.abs(np.angle(np.exp(1j * (centres[:, None] - np.asarray(angles)[None, :]))))
            nearest = np.argmin(diff, axis=1)
            ok = diff[np.arange(HUE_BINS), nearest] <= math.radians(hue_tolerance_deg)
            lut[:HUE_BINS][ok] = nearest[ok]
            lut[HUE_BINS] = lut[0]
        min_sat = min_saturation_fraction * (min(sats) if sats else 1.0)
        return cls(np.asarray(dirs, dtype=np.float32).reshape(-1, 2), np.asarray(sats), lut, min_sat)

    def classify(self, c1: F32, c2: F32, lum: F32) -> NDArray[np.int16]:
        """(H, W) chroma planes -> (H, W) int16 rover index per pixel (NO_ROVER for grey/dark/other hues)."""
        saturation, hue = cv2.cartToPolar(c1, c2)  # |c| and the hue angle 0..2pi, float32, in one pass
        # int32 indices and take(): a tenth of the time of intp and fancy indexing on a window (same classes)
        cls = self.hue_lut.take((hue * np.float32(HUE_BINS / (2.0 * math.pi))).astype(np.int32))
        weak = saturation < np.float32(self.min_relative_saturation) * np.maximum(lum, np.float32(4.0))
        np.putmask(cls, weak, NO_ROVER)  # a fraction of the cost of a boolean-indexed assignment
        return cls

    def plane(self, index: int, c1: F32, c2: F32) -> F32:
        """Colour-plane extraction for rover ``index``: chroma projected on its hue direction, (H, W) float32."""
        d = self.directions[index]
        return np.asarray(c1 * d[0] + c2 * d[1], dtype=np.float32)


def color_planes(bgr: U8, model: ColorModel) -> F32:
    """(H, W, 3) uint8 -> (N, H, W) float32: one plane per marker colour (the paper's R, G, B planes for N)."""
    c1, c2, _ = opponent_planes(bgr)
    return np.stack([model.plane(i, c1, c2) for i in range(model.directions.shape[0])])


# -- automatic threshold interval (section IV.C) -----------------------------------------------------------------
@dataclass(frozen=True)
class ThresholdInterval:
    """``k_min <= value <= k_max`` selects the marker (Fig. 11)."""

    k_min: float
    k_max: float


def auto_threshold(
    plane_roi: F32, candidates: BoolArray, fraction: float, percentile: float = 90.0, marker_px: float | None = None
) -> ThresholdInterval:
    """The threshold interval updated from the marker's maximum (Fig. 12).

    ``k_max`` is a high percentile of the plane over the candidate pixels (robust to a hot pixel, unlike the
    paper's plain maximum) and ``k_min = fraction * k_max``: with ``fraction = 0.5`` the boundary sits where a
    pixel is half covered by the marker. Returns ``k_max = 0`` when there are no candidates.

    ``marker_px``: the marker's expected area in pixels. When there are more candidates than that (a floor of the
    marker's hue class fills the window), the percentile is taken over that many of the brightest: the marker's
    own top, not the floor's (``edge.trackers.base.threshold_marker``).
    """
    vals = plane_roi[candidates]
    if vals.size == 0:
        return ThresholdInterval(0.0, 0.0)
    k = min(vals.size - 1, int(vals.size * percentile / 100.0))
    if marker_px is not None and vals.size > marker_px:
        k = vals.size - 1 - int(marker_px * (100.0 - percentile) / 100.0)
    vals.partition(k)  # in place: a fresh array
    k_max = float(vals[k])
    return ThresholdInterval(fraction * k_max, k_max)


def threshold(plane_roi: F32, interval: ThresholdInterval) -> BoolArray:
    """Binary image of the pixels inside the interval (the upper bound is open: glare can only lower a plane)."""
    return np.asarray(plane_roi >= np.float32(interval.k_min))


# -- morphology (P.M.O. erosion, A.M.O. hole filling) ------------------------------------------------------------
_SQUARES = {k: np.ones((2 * k + 1, 2 * k + 1), np.uint8) for k in range(1, 9)}


def _square(k: int) -> NDArray[np.uint8]:
    """The (2k+1)-square structuring element: one pass of it is k passes of the 3x3 square."""
    kernel = _SQUARES.get(k)
    return kernel if kernel is not None else np.ones((2 * k + 1, 2 * k + 1), np.uint8)


def erode(mask: BoolArray, iterations: int = 1) -> BoolArray:
    """Binary erosion, ``iterations`` times with a 3x3 structuring element (the paper's P.M.O.)."""
    if iterations <= 0:
        return mask
    out = cv2.erode(mask.view(np.uint8), _square(iterations), borderType=cv2.BORDER_REPLICATE)
    return out.view(bool)


def dilate(mask: BoolArray, iterations: int = 1) -> BoolArray:
    """Binary dilation, ``iterations`` times with a 3x3 structuring element."""
    if iterations <= 0:
        return mask
    return cv2.dilate(mask.view(np.uint8), _square(iterations)).view(bool)


def close(mask: BoolArray, iterations: int = 1) -> BoolArray:
    """Binary closing, ``iterations`` times with a 3x3 structuring element: gaps and notches up to twice that wide
    filled, the outline elsewhere unchanged (the image's border too: nothing beyond it is taken as set)."""
    if (k := iterations) <= 0:
        return mask
    padded = cv2.copyMakeBorder(mask.view(np.uint8), k, k, k, k, cv2.BORDER_CONSTANT, value=0)
    return np.ascontiguousarray(cv2.morphologyEx(padded, cv2.MORPH_CLOSE, _square(k))[k:-k, k:-k]).view(bool)


def edge_band(mask: BoolArray) -> BoolArray:
    """The pixels within one of the boundary of ``mask``, inside and out (the 3x3 morphological gradient)."""
    return cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_GRADIENT, _square(1), borderType=cv2.BORDER_REPLICATE).view(
        bool
    )


def reconstruct(marker: BoolArray, mask: BoolArray, connectivity: int = 8) -> BoolArray:
    """Binary morphological reconstruction ``R_mask(marker)``: the components of ``mask`` that ``marker`` touches.

    Iterated conditional dilation of the marker inside the mask converges to exactly these components; labelling
    them once is the same result in one pass.
    """
    n, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=connectivity)
    if n <= 1:
        return np.zeros_like(mask)
    if n == 2:  # one component (a tracked marker's window, nearly always): all of it or nothing
        return mask.copy() if np.count_nonzero(marker & mask) else np.zeros_like(mask)
    hit = np.zeros(n, bool)
    hit[labels[marker & mask]] = True
    hit[0] = False
    return hit.take(np.asarray(labels, np.intp))


def fill_holes(mask: BoolArray) -> BoolArray:
    """Automatic hole filling by reconstruction (Fig. 13): ``H = [R_{I^c}(F)]^c``.

    ``F`` is ``1 - I`` on the image border and 0 inside; reconstructing it inside the complement ``I^c`` reaches
    every background pixel connected to the border (4-connectivity, so 8-connected marker outlines close holes);
    everything else (the marker and its holes) is the filled result. A flood fill from a padded border is the
    same reconstruction in one pass.
    """
    h, w = mask.shape
    padded = cv2.copyMakeBorder(mask.view(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    ff_mask = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(padded, ff_mask, (0, 0), 2, flags=4)
    return np.asarray(padded[1:-1, 1:-1] != 2)


def open_by_reconstruction(mask: BoolArray, iterations: int = 1) -> BoolArray:
    """Erode to remove speckle noise, then reconstruct: surviving particles keep their exact outline."""
    if iterations <= 0:
        return mask
    return reconstruct(erode(mask, iterations), mask)


# -- particles (Table II) ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Particle:
    """One connected component of a binary image (pixel units, coordinates in the image it came from).

    ``area_px``: pixels excluding holes; ``holes_px``: area of its holes; ``hull_px``: convex hull area;
    ``bbox``: ``(x0, y0, x1, y1)`` exclusive; ``centre_px``: centre of mass (eq. 9-10); ``label``: its label in
    the label image it came from.
    """

    label: int
    area_px: int
    holes_px: int
    hull_px: float
    bbox: tuple[int, int, int, int]
    centre_px: tuple[float, float]

    @property
    def total_px(self) -> int:
        """Particle area plus the area of its holes (Table II 'Total Area')."""
        return self.area_px + self.holes_px

    @property
    def solidity(self) -> float:
        """Total area over convex hull area: 1 for a convex marker, low for merged or ragged blobs."""
        return self.total_px / self.hull_px if self.hull_px > 0 else 1.0


def label_particles(
    mask: BoolArray, min_area_px: int = 1, filled: bool = False
) -> tuple[NDArray[np.int32], list[Particle]]:
    """Label the 8-connected particles of ``mask``; measure each as in Table II (holes, hull, bounding box).

    Returns the (H, W) int32 label image and the particles with at least ``min_area_px`` pixels. ``filled``: the
    mask's holes are filled already (:func:`fill_holes`): no particle has any.
    """
    m8 = mask.view(np.uint8)
    if filled:
        # Without holes no particle lies inside another, so the external outlines are the particles (8-connected, as
        # the labelling's): one (a tracked marker's window, nearly always) is measured from its outline and the mask
        # alone (the same integers as the labelling's statistics, which cost five times the labelling itself).
        contours, _ = cv2.findContours(m8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if len(contours) == 1:
            return np.asarray(mask, np.int32), outline_particle(mask, contours[0], min_area_px)
    n, labels, stats, centroids = cv2.connectedComponentsWithStatsWithAlgorithm(m8, 8, cv2.CV_32S, cv2.CCL_GRANA)
    found: list[tuple[int, int, tuple[int, int, int, int], BoolArray, tuple[float, float]]] = []
    for i in range(1, n):
        area = int(stats[i, cv2.CC_STAT_AREA])
        if area < min_area_px:
            continue
        x, y, w, h = (int(stats[i, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, 3))
        centre = (float(centroids[i, 0]), float(centroids[i, 1]))
        found.append((i, area, (x, y, w, h), labels[y : y + h, x : x + w] == i, centre))
    out: list[Particle] = []
    for i, area, (x, y, w, h), sub, centre in found:
        whole = sub if filled else fill_holes(sub)
        holes = 0 if filled else int(whole.sum()) - area
        contours, _ = cv2.findContours(whole.view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        points = contours[0] if len(contours) == 1 else np.vstack(contours) if contours else None
        hull = float(cv2.contourArea(cv2.convexHull(points))) if points is not None else float(area)
        hull = max(hull, float(area + holes))  # contourArea runs through pixel centres: never below the count
        out.append(Particle(i, area, holes, hull, (x, y, x + w, y + h), centre))
    return np.asarray(labels, np.int32), out


def single_outline(mask: BoolArray, iterations: int) -> tuple[np.ndarray, bool, BoolArray] | None:
    """The outer outline of a ``mask`` that is one 8-connected particle (a tracked marker's window, nearly always),
    whether it has holes and its erosion, from one outline pass; None when it is not one particle that survives
    :func:`open_by_reconstruction` (whole). Then that opening is ``mask`` itself, its :func:`fill_holes` is ``mask``
    when it has no holes, and ``outline_particle(filled, outline, ...)`` is its :func:`label_particles`.

    The outlines' two-level hierarchy has one outer outline per particle (one inside another's hole too) and one per
    hole; a particle's outer outline is its filling's."""
    contours, hierarchy = cv2.findContours(mask.view(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return None
    outer = [c for c, link in zip(contours, hierarchy[0].tolist(), strict=True) if link[3] < 0]
    if len(outer) != 1:
        return None
    eroded = erode(mask, iterations)
    if iterations > 0 and not np.count_nonzero(eroded):
        return None
    return outer[0], len(contours) > 1, eroded


def outline_particle(mask: BoolArray, outline: np.ndarray, min_area_px: int) -> list[Particle]:
    """The one particle of a hole-free ``mask`` whose external ``outline`` (``cv2.findContours``) is given (none when
    it has fewer than ``min_area_px`` pixels)."""
    sums = ramp(mask.shape[0]).T @ mask.view(np.uint8) @ ramp(mask.shape[1])  # integers: exact in doubles
    area = int(sums[0, 0])
    if area < min_area_px:
        return []
    x, y, w, h = cv2.boundingRect(outline)
    centre = (float(sums[0, 1]) / area, float(sums[1, 0]) / area)
    hull = max(float(cv2.contourArea(cv2.convexHull(outline))), float(area))  # never below the pixel count
    return [Particle(1, area, 0, hull, (x, y, x + w, y + h), centre)]
