"""Exact area coverage of polygons over a pixel grid: the simulator's sub-pixel geometry.

A camera pixel integrates the light falling on its square; the fraction of a pixel's square that a polygon covers is
what a perfectly focused, box-filtered sensor records at the polygon's edge. This module computes that fraction
exactly (to float rounding) for any simple polygon, so a marker is drawn where the camera model projects it with no
supersampling bias.

Method (Green's theorem, as in area-accumulating font rasterisers): the area of a polygon ``P`` inside the pixel
band ``r <= y < r + 1`` and the column ``c <= x < c + 1`` is ``sum over edges of sign(dx) * integral over the edge's
x-range within the column of clamp(y(x) - r, 0, 1) dx``. Rows the edge lies wholly below contribute the full
``dx`` and are filled with one difference array and a cumulative sum; only the rows the edge crosses are computed
explicitly. The cost grows with the polygon's perimeter, not its area.

Pixel convention: pixel centres at integer coordinates (as :meth:`edge.camera.PinholeCamera.project` returns them),
so pixel ``(row, col)`` covers ``[col - 0.5, col + 0.5) x [row - 0.5, row + 0.5)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def polygon_area(xy_px: FloatArray) -> float:
    """Signed shoelace area of an (N, 2) polygon (positive when counter-clockwise in x-right, y-up axes)."""
    x, y = xy_px[:, 0], xy_px[:, 1]
    return 0.5 * float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]) + x[-1] * y[0] - x[0] * y[-1])


def polygon_centroid(xy_px: FloatArray) -> FloatArray:
    """(2,) area centroid of an (N, 2) simple polygon."""
    x, y = xy_px[:, 0], xy_px[:, 1]
    x1, y1 = _next(x), _next(y)
    cross = x * y1 - x1 * y
    area6 = 3.0 * np.sum(cross)
    return np.array([np.sum((x + x1) * cross) / area6, np.sum((y + y1) * cross) / area6])


def _next(a: FloatArray) -> FloatArray:
    """The array rotated by one along its first axis (a cheaper ``np.roll(a, -1, axis=0)``)."""
    return np.concatenate([a[1:], a[:1]])


def coverage(
    polygons_px: Sequence[FloatArray],
    origin_px: tuple[int, int],
    shape: tuple[int, int],
    groups: Sequence[int] | None = None,
) -> FloatArray:
    """Exact fraction of each pixel of a window covered by each polygon.

    ``polygons_px``: K polygons, each (N_k, 2) float pixel coordinates (pixel centres at integers), either winding.
    ``origin_px``: ``(col, row)`` of the window's top-left pixel. ``shape``: ``(rows, cols)`` of the window.
    ``groups``: optional output index of each polygon, to get the summed coverage of disjoint polygons (e.g. the
    black cells of a tag) in one map.
    Returns (G, rows, cols) float64 in [0, 1], G = K without ``groups``. Parts of a polygon outside the window are
    simply not counted.
    """
    rows, cols = shape
    n_polys = len(polygons_px)
    group_of = np.arange(n_polys) if groups is None else np.asarray(groups, dtype=np.int64)
    k_count = int(group_of.max()) + 1 if n_polys else 0
    out = np.zeros((k_count, rows, cols))
    if k_count == 0 or rows <= 0 or cols <= 0:
        return out
    shift = np.array([origin_px[0] - 0.5, origin_px[1] - 0.5])  # pixel (r, c) becomes [c, c+1) x [r, r+1)
    lengths = {len(p) for p in polygons_px}
    if len(lengths) == 1:  # the common case (quadrilaterals): all polygons at once
        pts = np.asarray(polygons_px, dtype=np.float64) - shift  # (K, N, 2)
        nxt = np.concatenate([pts[:, 1:], pts[:, :1]], axis=1)
        doubled = np.sum(pts[..., 0] * nxt[..., 1] - nxt[..., 0] * pts[..., 1], axis=1)
        signs = np.where(doubled < 0, -1.0, 1.0)
        a, b = pts.reshape(-1, 2), nxt.reshape(-1, 2)
        edge_owner = np.repeat(np.arange(n_polys), pts.shape[1])
    else:
        starts, ends, owner, signs = [], [], [], np.empty(n_polys)
        for k, poly in enumerate(polygons_px):
            p = np.asarray(poly, dtype=np.float64).reshape(-1, 2) - shift
            starts.append(p)
            ends.append(_next(p))
            owner.append(np.full(p.shape[0], k))
            signs[k] = -1.0 if polygon_area(p) < 0 else 1.0
        a = np.concatenate(starts)
        b = np.concatenate(ends)
        edge_owner = np.concatenate(owner)
    xa, ya, xb, yb = a[:, 0], a[:, 1], b[:, 0], b[:, 1]
    keep = xa != xb  # vertical edges bound no area in x
    xa, ya, xb, yb, edge_owner = xa[keep], ya[keep], xb[keep], yb[keep], edge_owner[keep]
    if xa.size == 0:
        return out
    slope = (yb - ya) / (xb - xa)
    # Orientation: with y pointing down, sum(sign(dx) * area below) counts clockwise-on-screen polygons positive.
    edge_sign = np.sign(xb - xa) * signs[edge_owner] * -1.0
    x_lo, x_hi = np.minimum(xa, xb), np.maximum(xa, xb)
    c_first = np.clip(np.floor(x_lo), 0, cols).astype(np.int64)
    c_last = np.clip(np.ceil(x_hi), 0, cols).astype(np.int64)
    n_cols = np.maximum(c_last - c_first, 0)
    total = int(n_cols.sum())
    if total == 0:
        return out
    # One entry per (edge, column) pair the edge crosses.
    e = np.repeat(np.arange(xa.size), n_cols)
    first_of_edge = np.repeat(np.cumsum(n_cols) - n_cols, n_cols)
    col = c_first[e] + (np.arange(total) - first_of_edge)
    xl = np.maximum(col, x_lo[e])
    xr = np.minimum(col + 1.0, x_hi[e])
    dx = xr - xl
    y_at_l = ya[e] + slope[e] * (xl - xa[e])
    y_at_r = ya[e] + slope[e] * (xr - xa[e])
    y_min = np.minimum(y_at_l, y_at_r)
    y_max = np.maximum(y_at_l, y_at_r)
    weight = edge_sign[e] * dx
    k_of = group_of[edge_owner[e]]

    # Rows wholly above the edge segment (y < floor(y_min)) are covered across the segment's whole dx.
    full_end = np.clip(np.floor(y_min), 0, rows).astype(np.int64)
    diff_index = (k_of * (rows + 1) * cols)[:, None] + np.stack([col, full_end * cols + col], axis=1)
    diff = np.bincount(
        diff_index.ravel(),
        weights=np.stack([weight, -weight], axis=1).ravel(),
        minlength=k_count * (rows + 1) * cols,
    ).reshape(k_count, rows + 1, cols)
    out += np.cumsum(diff, axis=1)[:, :rows, :]

    # Rows the edge segment crosses: mean over the segment of clamp(y - r, 0, 1), from G(t) = mean(max(y - t, 0)).
    r_first = np.floor(y_min).astype(np.int64)
    r_count = np.maximum(np.ceil(y_max).astype(np.int64) - r_first, 1)
    pair = np.repeat(np.arange(total), r_count)
    first_of_pair = np.repeat(np.cumsum(r_count) - r_count, r_count)
    row = r_first[pair] + (np.arange(pair.size) - first_of_pair)
    inside = (row >= 0) & (row < rows)
    pair, row = pair[inside], row[inside]
    lo, hi = y_min[pair], y_max[pair]
    span = hi - lo
    frac = _mean_excess(lo, hi, span, row.astype(np.float64)) - _mean_excess(lo, hi, span, row + 1.0)
    flat = (k_of[pair] * rows + row) * cols + col[pair]
    out += np.bincount(flat, weights=weight[pair] * frac, minlength=k_count * rows * cols).reshape(k_count, rows, cols)
    np.clip(out, 0.0, 1.0, out=out)
    return out


def _mean_excess(lo: FloatArray, hi: FloatArray, span: FloatArray, t: FloatArray) -> FloatArray:
    """Mean over a straight segment of ``max(y - t, 0)``, the segment's y running linearly from lo to hi."""
    with np.errstate(divide="ignore", invalid="ignore"):
        partial = np.where(span > 0, (hi - t) ** 2 / (2.0 * span), 0.0)
    return np.where(lo >= t, 0.5 * (lo + hi) - t, np.where(hi <= t, 0.0, partial))
