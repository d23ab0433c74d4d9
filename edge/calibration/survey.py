"""Where to survey calibration points: a layout that minimises the worst predicted error over the working area.

The far edge of an oblique view has the fewest pixels per cm (about 0.45 px/cm vertically in the paper's
geometry) and dominates the maximum error, so evenly spread points waste most of the survey on the near side.
Given a rough plane mapping (for a real camera: from the four corners of the area, measured first), this picks
``n`` distinct points of the survey grid that minimise the largest predicted mean squared position error over the
area (a G-optimal design, Fedorov exchange) for the image-space homography fit of :mod:`edge.calibration.points`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from edge.calibration.homography import _param_jacobian, _world_jacobian, apply_homography, normaliser
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]


def grid_candidates(width_cm: float, length_cm: float, grid_cm: float) -> FloatArray:
    """(M, 2) the intersections of a ``grid_cm`` grid from the origin, inside ``[0, width] x [0, length]``."""
    xs = np.arange(0.0, width_cm + 1e-9, grid_cm)
    ys = np.arange(0.0, length_cm + 1e-9, grid_cm)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel()])


def plan_survey(
    g_world_to_px: FloatArray,
    candidates_cm: FloatArray,
    area_cm: tuple[float, float, float, float],
    n: int,
    *,
    max_sweeps: int = 8,
) -> NDArray[np.int64]:
    """Indices (sorted) of ``n`` candidates forming a G-optimal survey layout.

    ``g_world_to_px``: (3, 3) rough world -> pixel homography of the plane. ``candidates_cm``: (M, 2) allowed points.
    ``area_cm``: ``(x0, y0, x1, y1)`` of the working area over which the worst case is taken.
    """
    cand = np.asarray(candidates_cm, dtype=np.float64).reshape(-1, 2)
    m = cand.shape[0]
    if n < 4 or n > m:
        raise CalibrationError(f"cannot choose {n} survey points out of {m} candidates")
    x0, y0, x1, y1 = area_cm
    ex, ey = np.meshgrid(np.linspace(x0, x1, 9), np.linspace(y0, y1, 12), indexing="ij")
    evals = np.column_stack([ex.ravel(), ey.ravel()])
    t_world = normaliser(cand)
    t_px = normaliser(apply_homography(g_world_to_px, cand))
    gn = t_px @ g_world_to_px @ np.linalg.inv(t_world)
    params = np.asarray((gn / gn[2, 2]).ravel()[:8])
    jc = _param_jacobian(params, t_world, t_px, cand)  # (M, 2, 8)
    outer = np.einsum("mik,mil->mkl", jc, jc)  # (M, 8, 8)
    je = _param_jacobian(params, t_world, t_px, evals)
    me = -np.einsum("kij,kjp->kip", np.linalg.inv(_world_jacobian(g_world_to_px, evals)), je)  # (K, 2, 8)
    gram = np.einsum("kip,kiq->kpq", me, me)  # trace(M C M^T) = sum(C * M^T M)

    def worst(info: FloatArray) -> FloatArray:
        """(B,) max over the area of the predicted mean squared error, for a batch (B, 8, 8) of designs."""
        cov = np.linalg.pinv(info, hermitian=True)
        return np.asarray(np.einsum("bpq,kpq->bk", cov, gram).max(axis=1))

    # start from the candidates nearest the area's corners: the smallest design that determines the mapping
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    chosen = list(dict.fromkeys(int(np.argmin(np.linalg.norm(cand - c, axis=1))) for c in corners))
    info = outer[chosen].sum(axis=0)
    while len(chosen) < n:
        free = np.setdiff1d(np.arange(m), chosen)
        scores = worst(info[None] + outer[free])
        best = int(free[int(np.argmin(scores))])
        chosen.append(best)
        info = info + outer[best]
    current = float(worst(info[None])[0])
    for _ in range(max_sweeps):
        improved = False
        for pos in range(n):
            free = np.setdiff1d(np.arange(m), chosen)
            trial = info[None] - outer[chosen[pos]] + outer[free]
            scores = worst(trial)
            k = int(np.argmin(scores))
            if scores[k] < current * (1.0 - 1e-9):
                info = trial[k]
                chosen[pos] = int(free[k])
                current = float(scores[k])
                improved = True
        if not improved:
            break
    return np.sort(np.asarray(chosen, dtype=np.int64))
