"""Mean shift (paper section V.C, eq. 11-20): climb to the mode of the rover's colour-histogram likelihood.

The target model is a kernel-weighted histogram of the marker's pixels (eq. 11-12), the candidate the same
histogram around the current position (eq. 15-16); each pixel is weighted by ``sqrt(q_u / p_u)`` of its bin
(eq. 19) and the kernel moves to the weighted mean (eq. 20, Epanechnikov kernel, so ``g`` is constant inside it)
until it stops. The model is blended with the newest appearance after each frame. The feature is the rover's
colour plane (the paper's 8-bit plane of its colour), normalised by the marker's level so the bins do not shift
when the light changes; pixels of other hues share bin 0.

The kernel is an ellipse in the image: the marker's circumscribed circle on the plane, seen through the local
plane mapping, so it is as wide as the marker everywhere in the field. The final position is the area centroid
on the plane of the marker's coverage over the pixels of its colour under the converged kernel.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numpy.typing import NDArray

from edge.segmentation import auto_threshold
from edge.trackers.base import (
    Measurement,
    RoverModel,
    StageClock,
    Window,
    area_quality,
    make_measurement,
    world_blob,
)


class MeanShiftTracker:
    """Mean shift on the marker's colour-plane histogram (eq. 11-20) inside the search window."""

    name = "meanshift"

    def __init__(
        self,
        bins: int = 8,
        max_iterations: int = 20,
        epsilon_px: float = 0.02,
        blend: float = 0.1,
        kernel_scale: float = 1.25,
    ) -> None:
        self.bins = bins
        self.max_iterations = max_iterations
        self.epsilon_px = epsilon_px
        self.blend = blend
        self.kernel_scale = kernel_scale
        self._models: dict[int, NDArray[np.float64]] = {}

    def reset(self, index: int) -> None:
        """Forget the target model of rover ``index`` (it was lost; the next measurement re-models it)."""
        self._models.pop(index, None)

    def measure(self, window: Window, rover: RoverModel, clock: StageClock) -> Measurement | None:
        t0 = time.perf_counter()
        candidates = window.classes == rover.index
        if not candidates.any():
            clock.add("threshold", time.perf_counter() - t0)
            return None
        level = rover.marker_level
        if level <= 0.0:
            level = auto_threshold(window.plane, candidates, 0.5).k_max
        if level <= 0.0:
            return None
        coverage = window.plane * np.float32(1.0 / level)
        top = self.bins - 1
        feature = np.clip(coverage * np.float32(self.bins / 1.25), 0, top).astype(np.intp) + 1
        feature[~candidates] = 0
        t1 = time.perf_counter()
        clock.add("threshold", t1 - t0)

        h, w = feature.shape
        x0, y0 = window.offset
        grid_u = np.arange(w, dtype=np.float64) + x0
        grid_v = np.arange(h, dtype=np.float64) + y0
        metric = self._kernel_metric(window, rover)
        y = np.array(window.predicted_uv, dtype=np.float64)

        q = self._models.get(rover.index)
        if q is None:
            q = self._target_model(feature, coverage, grid_u, grid_v, y, metric)
            if q is None:
                clock.add("measure", time.perf_counter() - t1)
                return None
        rho = 0.0
        wts = np.zeros((h, w))
        for _ in range(self.max_iterations):
            kern, inside = _epanechnikov(grid_u, grid_v, y, metric)
            if not inside.any():
                break
            p = np.bincount(feature[inside], weights=kern[inside], minlength=self.bins + 1).astype(np.float64)  # eq. 15
            p /= max(float(p.sum()), 1e-12)  # eq. 16
            rho = float(np.sqrt(p * q).sum())  # eq. 17
            ratio = np.sqrt(q / np.maximum(p, 1e-12))  # eq. 19
            wts = np.where(inside, ratio[feature], 0.0)
            total = float(wts.sum())
            if total <= 0.0:
                break
            y_new = np.array([float(wts.sum(axis=0) @ grid_u), float(wts.sum(axis=1) @ grid_v)]) / total  # eq. 20
            shift = float(np.hypot(*(y_new - y)))
            y = y_new
            if shift < self.epsilon_px:
                break
        t2 = time.perf_counter()
        clock.add("measure", t2 - t1)
        # The measurement: marker coverage of the pixels under the converged kernel that carry the marker's colour.
        weights = np.where((wts > 0.0) & (feature > 0), np.clip(coverage, 0.0, 1.0), 0.0).astype(np.float32)
        blob = world_blob(weights, window.offset, window.grid)
        clock.add("calibration", time.perf_counter() - t2)
        if blob is None or rho <= 0.0:
            return None
        fresh = self._target_model(feature, coverage, grid_u, grid_v, y, metric)
        if fresh is not None:
            self._models[rover.index] = (1.0 - self.blend) * q + self.blend * fresh
        quality = area_quality(blob.area_cm2, rover.marker_area_cm2) * min(1.0, rho)
        return make_measurement(blob, window, weights > 0.5, level, quality, weights)

    def _kernel_metric(self, window: Window, rover: RoverModel) -> NDArray[np.float64]:
        """(2, 2) M such that ``d^T M d <= 1`` is the marker's circumscribed circle (times the kernel scale)."""
        u, v = window.predicted_uv
        eps = 0.5
        pts_u = np.array([u, u + eps, u])
        pts_v = np.array([v, v, v + eps])
        xs, ys = window.local.to_world(pts_u, pts_v)
        jac = np.array([[xs[1] - xs[0], xs[2] - xs[0]], [ys[1] - ys[0], ys[2] - ys[0]]]) / eps  # cm per px
        radius_cm = self.kernel_scale * math.sqrt(2.0 * rover.marker_area_cm2 / math.pi)
        return np.asarray(jac.T @ jac) / (radius_cm * radius_cm)

    def _target_model(
        self,
        feature: NDArray[np.intp],
        coverage: NDArray[np.float32],
        grid_u: NDArray[np.float64],
        grid_v: NDArray[np.float64],
        y: NDArray[np.float64],
        metric: NDArray[np.float64],
    ) -> NDArray[np.float64] | None:
        """eq. 11-12 over the marker's pixels (coverage above one half) under the kernel at ``y``."""
        kern, inside = _epanechnikov(grid_u, grid_v, y, metric)
        sel = inside & (feature > 0) & (coverage > 0.5)
        if not sel.any():
            return None
        q = np.bincount(feature[sel], weights=kern[sel], minlength=self.bins + 1).astype(np.float64)
        q[0] = 0.0
        q += 1e-3 * float(q.sum()) / q.size  # a floor keeps sqrt(q/p) finite for bins the model never saw
        return np.asarray(q / q.sum())


def _epanechnikov(
    grid_u: NDArray[np.float64], grid_v: NDArray[np.float64], y: NDArray[np.float64], metric: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Kernel profile ``k(d^2) = 1 - d^2`` (eq. 14) over the window and the mask where it is positive."""
    du = grid_u[None, :] - y[0]
    dv = grid_v[:, None] - y[1]
    d2 = metric[0, 0] * du * du + 2.0 * metric[0, 1] * du * dv + metric[1, 1] * dv * dv
    inside = d2 < 1.0
    return np.where(inside, 1.0 - d2, 0.0), inside
