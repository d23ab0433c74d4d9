"""The last step of every window tracker: the marker's centre and axis from its outline (``edge.outline``).

A tracker's area centroid (coverage-weighted pixels on the plane) finds the marker to within a pixel or so and
measures its area; this step moves the centre to the middle of the marker's fitted edges, which does not depend on
the camera's tone curve, blur or what surrounds the marker, and gives the marker's long axis from its edges (the
direction of a one-colour marker, modulo 180 degrees). Where the outline cannot be fitted (the marker glared out,
half in shadow, an edge shared with something of the same colour), the area centroid stands.

The fit costs most of a frame's time, so it runs only with the ``outline_fit`` setting (:func:`refine_outline`);
without it the pipeline takes only the axis from the edges (:func:`refine_axis`) and keeps the area centroid.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import replace

import cv2
import numpy as np

from edge.filtering import MIN_EDGE_COHERENCE  # below it the edges show no rectangle (edge.two_tone.edge_axis)
from edge.outline import fit_outline, marker_signal
from edge.segmentation import F32, BoolArray, edge_band, erode
from edge.trackers.base import Measurement, Window
from edge.two_tone import edge_axis, footprint_cm

MAX_SHIFT_PX = 1.0  # the outline may move the area centroid by this much, else it fitted something else
MAX_SIZE_ERROR = 0.08  # the fitted length and width must be the marker's within this share
MAX_RESIDUAL = 0.3  # the fit's RMS residual over the marker's level: above, the edges are not a clean rectangle


def refine_outline(
    window: Window,
    m: Measurement,
    size_cm: tuple[float, float],
    rover_index: int,
    exclude: BoolArray | None = None,
    jacobian: np.ndarray | None = None,
) -> Measurement:
    """``m`` with its centre (``xy_cm``) and axis (``axis_rad``) from the marker's fitted outline (``outlined``),
    or ``m`` with only the axis refined when the outline does not fit (not a clean rectangle of the marker's size
    within a pixel of the area centroid). ``size_cm``: the marker's (length, width); ``exclude``: pixels of other
    things (other rovers) in the window; ``jacobian``: ``window.local.jacobian(*m.uv_px)`` when the caller has it."""
    edges = _edge_signal(window, m, rover_index, exclude)
    if edges is None:
        return m
    signal, usable = edges
    x0, y0, x1, y1 = window.box
    x_cm = window.grid.x_cm[y0:y1, x0:x1]
    y_cm = window.grid.y_cm[y0:y1, x0:x1]
    if jacobian is None:
        jacobian = window.local.jacobian(*m.uv_px)
    axis, coherence = marker_axis((window.lum, signal), m, jacobian, usable, size_cm)
    cm_per_px = footprint_cm(jacobian, axis)
    fit = fit_outline(signal, x_cm, y_cm, m.xy_cm, axis, size_cm, cm_per_px, usable)
    if fit is None or fit.residual > MAX_RESIDUAL:
        return m.with_axis(axis, coherence)
    shift = math.hypot(fit.xy_cm[0] - m.xy_cm[0], fit.xy_cm[1] - m.xy_cm[1])
    size_error = max(abs(fit.size_cm[0] / size_cm[0] - 1.0), abs(fit.size_cm[1] / size_cm[1] - 1.0))
    if shift > MAX_SHIFT_PX * max(cm_per_px) or size_error > MAX_SIZE_ERROR:
        return m.with_axis(axis, coherence)
    return replace(m, xy_cm=fit.xy_cm, axis_rad=axis, axis_coherence=coherence, outlined=True)


def refine_axis(
    window: Window,
    m: Measurement,
    size_cm: tuple[float, float],
    rover_index: int,
    exclude: BoolArray | None = None,
    jacobian: np.ndarray | None = None,
) -> Measurement:
    """``m`` with its long axis (``axis_rad``) from the marker's edges (:func:`marker_axis`), its centre unchanged:
    the heading's part of :func:`refine_outline`, at a small part of its cost (``jacobian``: as there)."""
    if m.weights is None:
        return m
    if jacobian is None:
        jacobian = window.local.jacobian(*m.uv_px)
    usable = _usable(window, rover_index, exclude)
    return m.with_axis(*marker_axis(_edge_planes(window, m, rover_index, exclude), m, jacobian, usable, size_cm))


def _edge_planes(window: Window, m: Measurement, rover_index: int, exclude: BoolArray | None) -> Iterator[F32]:
    """The planes whose edges show the marker's outline, best first: the luminance (full resolution in every
    stream; the chroma of a 4:2:0 stream has half), then the marker's chroma (a marker as bright as its surround)."""
    yield window.lum
    edges = _edge_signal(window, m, rover_index, exclude)
    if edges is not None:
        yield edges[0]


def _usable(window: Window, rover_index: int, exclude: BoolArray | None) -> BoolArray | None:
    """The window's pixels not of other things: other rovers' hues, ``exclude``; None where that is all of them."""
    others = window.others(rover_index)  # None or some pixels
    if exclude is not None:
        others = exclude if others is None else others | exclude
        if not np.count_nonzero(others):
            return None
    return None if others is None else ~others


def _edge_signal(
    window: Window, m: Measurement, rover_index: int, exclude: BoolArray | None
) -> tuple[np.ndarray, BoolArray | None] | None:
    """The marker's chroma signal in linear light (``edge.outline.marker_signal``) and the window's usable pixels
    (:func:`_usable`); None without a marker interior to measure it from."""
    if m.weights is None:
        return None
    sample = erode(m.weights >= 1.0, 1)
    if not sample.any():
        return None
    signal = marker_signal(window.linear, sample)
    if signal is None:
        return None
    return signal, _usable(window, rover_index, exclude)


def marker_axis(
    planes: Iterable[F32],
    m: Measurement,
    jacobian: np.ndarray,
    usable: BoolArray | None,
    size_cm: tuple[float, float],
) -> tuple[float, float]:
    """The marker's long axis (modulo pi) on the plane and the coherence of the edges it came from (0..1): the
    directions of its edges (modulo pi/2, sharp) in the first of ``planes`` that shows them coherently, resolved by
    the blob's elongation (which of the two is the long one). Where the marker is square, or no plane shows a
    rectangle, the blob axis alone, with coherence 0 (``edge.filtering.checked_axis`` weighs it against the motion,
    the heading filter against the last frames).

    Only the marker's own edge counts: the band of pixels within one of the boundary of its coverage (``m.weights``
    at one half). Farther out the body's outline shows too, and where the camera sees a rover from the side, the
    edges of the body's visible side are not on the marker plane: taken with them, the lens scenario's far-field
    rovers were turned by 20 degrees."""
    if m.weights is None or abs(size_cm[0] - size_cm[1]) < 0.05 * max(size_cm):
        return m.axis_rad, 0.0
    half = m.weights >= 0.5
    x, y, w, h = cv2.boundingRect(half.view(np.uint8))
    if w == 0 or h == 0:
        return m.axis_rad, 0.0
    # Everything within two pixels of the half coverage's box: the band and the derivatives round it (the same
    # pixels and values as over the whole window)
    crop = (slice(max(0, y - 2), y + h + 2), slice(max(0, x - 2), x + w + 2))
    band = edge_band(half[crop])
    if usable is not None:
        band &= usable[crop]
    for plane in planes:
        axis4, strength = edge_axis(plane[crop], band, jacobian)
        if strength >= MIN_EDGE_COHERENCE:
            candidates = (axis4, axis4 + 0.5 * math.pi)
            long_axis = m.axis_rad if size_cm[0] >= size_cm[1] else m.axis_rad + 0.5 * math.pi
            best = min(candidates, key=lambda a: abs(math.remainder(a - long_axis, math.pi)))
            return math.remainder(best, math.pi), strength
    return m.axis_rad, 0.0
