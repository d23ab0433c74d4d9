"""The marker's centre from its outline: the four edges of its known rectangle, each fitted in linear light.

Why not the area centroid alone. A marker's edge pixels mix the marker with what surrounds it: the dark top and the
camera-facing side of the rover's body on the near side, the floor (through a thin margin of body) on the far side
and round the sides. An estimate that weighs those pixels by how much marker they *seem* to hold is pulled towards
one side as soon as that seeming is not linear in the true coverage: a camera's tone curve makes a pixel half
covered by a black body look three-quarters marker (the edge moves out on the dark side, towards the camera); JPEG's
half-resolution chroma spreads the marker's colour over its neighbours, and once linearised that spill counts far
more on the bright floor than on the dark body (the edge moves out on the bright side). Both grow with the optics'
blur. On the simulator's camera family the coverage-weighted area centroid was off by 0.05-0.4 cm towards the
camera, depending on the blur, the body's colour and the compression.

The fit uses what does not depend on the camera:

1. **Signal** (:func:`marker_signal`): the marker's chroma in *linear* light (the tone curve undone),
   ``(L - grey(L)) . u`` with ``u`` the marker's chroma direction: light mixes linearly, and what surrounds a marker
   (black, grey or white bodies, their shadows) is neutral and carries none of it.
2. **Model**, edge by edge, across the edge (``d``: signed distance on the marker plane, outwards): the marker's
   level ``C_M`` inside, then a margin of the body's top (neutral: 0) of width ``m``, then whatever lies beyond at
   level ``C_S`` (the floor, slightly tinted), both steps blurred by one width ``w``:
   ``C(d) = C_M Phi((e - d) / w) + C_S Phi((d - e - m) / w)``. ``e``, ``w``, ``C_M`` and ``C_S`` are fitted by
   Levenberg-Marquardt, the four edges at once (``C_M`` too, per edge: light may fall unevenly across a marker, at
   a sunlit patch's edge); ``m`` is searched on a grid. A step's *position* is where its symmetric blur is
   centred, so a blur of any width leaves it in place, and chroma spilled outwards in a compressed stream widens
   the step more than it moves its middle.
3. **Centre**: the middle of each pair of opposite edges, on the world plane; the pairs' spans are the marker's
   measured length and width (a check that the fit found the marker). Only pixels from the middle of each edge
   count (not the corners), and for a small far-side marker the opposite edge's blur reaches into each edge's
   samples equally from both sides, which leaves the middle where it is.

Pure functions over arrays; the pipeline gives the window's pixels, their plane coordinates and the marker's axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]
BoolArray = NDArray[np.bool_]

ITERATIONS = 6
REFINE_ITERATIONS = 4
BIN_PX = 0.25  # samples are averaged in bins this wide across an edge (in pixels)
REACH_CM = 4.0  # samples reach this far from an edge on the plane, or REACH_PX pixels where pixels are larger
REACH_PX = 5.0
CORNER_CM = 2.0  # samples this close to a corner (along the edge) are left out
MIN_SAMPLES = 8
MIN_BLUR_PX, MAX_BLUR_PX = 0.15, 4.0  # a step's width stays within these (pixel footprint and optics together)
MARGINS_PX = (0.0, 0.5, 1.2, 2.5, 5.0)  # the body's top showing round the marker (refined freely from the best)
SIZE_TOLERANCE = 0.25  # the fitted length and width may differ from the marker's by this share, else no fit
_Z = np.linspace(-8.0, 8.0, 3201)
_PDF = np.exp(-0.5 * _Z * _Z) / math.sqrt(2.0 * math.pi)
_CDF = np.cumsum(_PDF) * (_Z[1] - _Z[0])
_CDF = (_CDF - 0.5 * _PDF * (_Z[1] - _Z[0])) / _CDF[-1]  # trapezoid rule, normalised to end at 1


@dataclass(frozen=True)
class OutlineFit:
    """The fitted outline: ``xy_cm`` the marker's centre on the plane; ``size_cm`` its measured (length, width);
    ``edges_cm`` each edge's offset from where it was expected (front, back, left, right; outwards positive);
    ``blur_cm`` each edge's step width; ``residual`` the fit's RMS residual over the marker's level."""

    xy_cm: tuple[float, float]
    size_cm: tuple[float, float]
    edges_cm: tuple[float, float, float, float]
    blur_cm: tuple[float, float, float, float]
    residual: float


def marker_signal(linear: F32, sample: BoolArray, white: FloatArray | None = None) -> F32 | None:
    """(h, w) the marker's chroma in linear light: each pixel's colour less its grey, projected on the chroma of
    the ``sample`` pixels (the marker's interior). ``linear``: (h, w, 3) linear BGR; ``white``: the light's colour,
    (3,) or (h, w, 3), to judge colours against (None: the camera's grey). None when the sample has no chroma."""
    if not sample.any():
        return None
    lin = np.asarray(linear if white is None else linear / np.maximum(white, 1e-6), dtype=np.float32)
    mean = np.asarray(cv2.mean(lin, mask=sample.view(np.uint8))[:3], dtype=np.float64)
    direction = mean - mean.mean()  # the sample's mean chroma
    norm = float(np.linalg.norm(direction))
    if norm < 1e-6:
        return None
    # A chroma direction sums to zero over the channels, so projecting the colour is projecting its chroma.
    unit = (direction / norm).astype(np.float32).reshape(1, 3)
    return np.asarray(cv2.transform(lin, unit), dtype=np.float32).reshape(lin.shape[:2])


def fit_outline(
    signal: F32,
    x_cm: FloatArray,
    y_cm: FloatArray,
    centre_cm: tuple[float, float],
    axis_rad: float,
    size_cm: tuple[float, float],
    cm_per_px: tuple[float, float],
    usable: BoolArray | None = None,
) -> OutlineFit | None:
    """The marker's centre from its four edges (see the module's docstring).

    ``signal``: (h, w) from :func:`marker_signal`; ``x_cm``, ``y_cm``: (h, w) each pixel's position on the marker
    plane; ``centre_cm``, ``axis_rad``: where the marker is roughly (within a pixel or two) and its long axis
    (modulo pi); ``size_cm``: its (length, width); ``cm_per_px``: a pixel's extent on the plane along the axis and
    across it; ``usable``: pixels that may count (not another rover's). None when an edge cannot be fitted.
    """
    c, s = math.cos(axis_rad), math.sin(axis_rad)
    dx = x_cm - centre_cm[0]
    dy = y_cm - centre_cm[1]
    along = dx * c + dy * s
    across = dy * c - dx * s
    length, width = size_cm
    halves = (0.5 * length, 0.5 * length, 0.5 * width, 0.5 * width)
    ok = np.ones(signal.shape, bool) if usable is None else usable
    core = ok & (np.abs(along) < 0.5 * length - 2.0 * cm_per_px[0] - 1.0)
    core &= np.abs(across) < 0.5 * width - 2.0 * cm_per_px[1] - 1.0
    if int(core.sum()) < 3:
        return None
    level = float(np.median(signal[core]))
    if level <= 1e-6:
        return None
    samples = []
    for k, (normal, parallel) in enumerate(((along, across), (-along, across), (across, along), (-across, along))):
        px_n = cm_per_px[0] if k < 2 else cm_per_px[1]
        half_other = halves[3] if k < 2 else halves[0]
        d = normal - halves[k]
        pick = ok & (np.abs(d) < max(REACH_CM, REACH_PX * px_n)) & (np.abs(parallel) < half_other - CORNER_CM)
        index = np.flatnonzero(pick)
        if index.size < MIN_SAMPLES:
            return None
        samples.append((d.ravel()[index], signal.ravel()[index].astype(np.float64), px_n))
    edges = fit_edges(samples, level)
    if edges is None:
        return None
    e, w, rms = edges
    measured = (length + e[0] + e[1], width + e[2] + e[3])
    if abs(measured[0] / length - 1.0) > SIZE_TOLERANCE or abs(measured[1] / width - 1.0) > SIZE_TOLERANCE:
        return None
    shift_along = 0.5 * (e[0] - e[1])
    shift_across = 0.5 * (e[2] - e[3])
    x = centre_cm[0] + shift_along * c - shift_across * s
    y = centre_cm[1] + shift_along * s + shift_across * c
    return OutlineFit(
        (x, y),
        measured,
        (float(e[0]), float(e[1]), float(e[2]), float(e[3])),
        (float(w[0]), float(w[1]), float(w[2]), float(w[3])),
        rms / level,
    )


def fit_edges(
    samples: list[tuple[FloatArray, FloatArray, float]], level: float
) -> tuple[FloatArray, FloatArray, float] | None:
    """Fit the edge model to each edge's samples ``(d_cm, value, px_cm)`` with the marker's ``level``: each edge's
    position and width (cm) and the fit's RMS residual.

    The samples are averaged in bins a quarter of a pixel wide across the edge (a near-side edge has thousands of
    pixels; its profile is what matters). The margin ``m`` is not well determined when the floor's tint is faint,
    and a local search from one start wanders; each edge is fitted from every margin of a grid (:data:`MARGINS_PX`,
    in pixels) with the margin held, then from the best of them with the margin free (Levenberg-Marquardt, all
    edges and starts batched)."""
    n_edges = len(samples)
    px = np.array([p for _, _, p in samples])
    binned = [_bins(d, v, BIN_PX * p) for d, v, p in samples]
    size = max(len(b[0]) for b in binned)
    d = np.zeros((n_edges, size))
    v = np.zeros((n_edges, size))
    weight = np.zeros((n_edges, size))  # counts; padding counts for nothing
    for k, (dk, vk, nk) in enumerate(binned):
        d[k, : len(dk)], v[k, : len(dk)], weight[k, : len(dk)] = dk, vk, nk
    margins = np.asarray(MARGINS_PX)[None, :] * px[:, None]  # (edges, grid)
    grid = margins.shape[1]
    outer = np.array([float(vk[dk > dk.max() - 1.5 * p].mean()) for dk, vk, p in samples])
    # parameters per edge and margin: position e, width w, outer level, marker level, margin m (the margin's level
    # is the body's: 0). The marker's level is each edge's own: light falls unevenly (a sunlit patch's edge).
    q = np.stack(
        [
            np.zeros((n_edges, grid)),
            np.repeat((1.2 * px)[:, None], grid, 1),
            np.repeat(outer[:, None], grid, 1),
            np.full((n_edges, grid), level),
            margins,
        ],
        axis=2,
    )
    data = (d[:, None, :], v[:, None, :], weight[:, None, :])
    limits = ((MIN_BLUR_PX * px)[:, None], (MAX_BLUR_PX * px)[:, None])
    q, cost = _levenberg_marquardt(data, q, limits, False, ITERATIONS)  # each margin of the grid
    best = np.argmin(cost, axis=1)
    q = q[np.arange(n_edges), best][:, None, :]
    q, cost = _levenberg_marquardt(data, q, limits, True, REFINE_ITERATIONS)  # then the margin too, from the best
    chosen = q[:, 0]
    if not np.all(np.isfinite(chosen)):
        return None
    rms = math.sqrt(float(cost.sum()) / max(float(weight.sum()), 1.0))
    return chosen[:, 0], chosen[:, 1], rms


def _levenberg_marquardt(
    data: tuple[FloatArray, FloatArray, FloatArray],
    q: FloatArray,
    limits: tuple[FloatArray, FloatArray],
    free_margin: bool,
    iterations: int,
) -> tuple[FloatArray, FloatArray]:
    """Damped Gauss-Newton steps on every (edge, start) problem at once: ``q`` (edges, starts, 5); returns the
    parameters and each problem's cost. ``data``: binned distances, values and counts, (edges, 1, bins) each;
    ``limits``: the width's bounds per edge."""
    d, v, w = data
    free = np.array([1.0, 1.0, 1.0, 1.0, 1.0 if free_margin else 0.0])
    eye = np.eye(5)
    resid, parts = _edge_model(d, v, q)
    cost = (w * resid * resid).sum(axis=2)
    lam = np.full(cost.shape, 1e-3)
    for _ in range(iterations):
        jac = _edge_jacobian(parts, q) * free[:, None]  # (edges, starts, 5, bins)
        a = np.einsum("kgin,kgjn->kgij", jac * w[:, :, None, :], jac)
        g = np.einsum("kgin,kgn->kgi", jac, resid * w)
        damped = a + lam[..., None, None] * (a * eye) + 1e-12 * eye
        trial = q + np.linalg.solve(damped, g[..., None])[..., 0]
        trial[..., 1] = np.clip(trial[..., 1], limits[0], limits[1])
        new_resid, new_parts = _edge_model(d, v, trial)
        new_cost = (w * new_resid * new_resid).sum(axis=2)
        better = new_cost <= cost
        if better.all():
            q, resid, parts, cost = trial, new_resid, new_parts, new_cost
        else:
            keep = better[..., None]
            q = np.where(keep, trial, q)
            resid = np.where(keep, new_resid, resid)
            parts = tuple(np.where(keep, n, o) for n, o in zip(new_parts, parts, strict=True))
            cost = np.where(better, new_cost, cost)
        lam = np.where(better, np.maximum(lam * 0.3, 1e-7), lam * 10.0)
    return q, cost


def _bins(d_cm: FloatArray, value: FloatArray, width_cm: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Samples averaged in bins of ``width_cm`` across the edge: (mean distance, mean value, count) of the bins
    that hold any."""
    index = np.floor((d_cm - d_cm.min()) / width_cm).astype(np.intp)
    count = np.bincount(index)
    keep = count > 0
    n = count[keep].astype(np.float64)
    return np.bincount(index, d_cm)[keep] / n, np.bincount(index, value)[keep] / n, n


def _phi(z: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The standard normal's cumulative distribution and density at ``z``, interpolated in tables (0.005 apart:
    errors below 1e-6; two table look-ups are much cheaper than an erf)."""
    return np.interp(z, _Z, _CDF), np.interp(z, _Z, _PDF)


def _edge_model(d: FloatArray, v: FloatArray, q: FloatArray) -> tuple[FloatArray, tuple[FloatArray, ...]]:
    """Residual ``v - C(d)`` for parameters ``q`` (..., 5: position, width, outer level, marker level, margin) and
    the pieces the Jacobian needs. The margin enters as ``|m|``: a search passes through 0 instead of sticking."""
    e, w, outer, level, m = q[..., 0:1], q[..., 1:2], q[..., 2:3], q[..., 3:4], q[..., 4:5]
    z_in = (e - d) / w  # the marker's step (marker inside, d < e)
    z_out = (d - e - np.abs(m)) / w  # the outer step, beyond the margin
    inside, pdf_in = _phi(z_in)
    beyond, pdf_out = _phi(z_out)
    return v - (level * inside + outer * beyond), (z_in, z_out, pdf_in, pdf_out, beyond, inside)


def _edge_jacobian(parts: tuple[FloatArray, ...], q: FloatArray) -> FloatArray:
    """(..., 5, samples) derivative of the model with respect to (position, width, outer level, marker level,
    margin)."""
    z_in, z_out, pdf_in, pdf_out, beyond, inside = parts
    w, outer, level, m = q[..., 1:2], q[..., 2:3], q[..., 3:4], q[..., 4:5]
    return np.stack(
        [
            (level * pdf_in - outer * pdf_out) / w,
            -(level * pdf_in * z_in + outer * pdf_out * z_out) / w,
            beyond,
            inside,
            -outer * pdf_out / w * np.where(m < 0, -1.0, 1.0),
        ],
        axis=-2,
    )
