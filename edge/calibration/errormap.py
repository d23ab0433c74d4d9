"""The calibration error map (paper Fig. 3/4): for every pixel, the predicted 95% position error in cm.

What it contains: the uncertainty of the fitted mapping itself, propagated from the homography's parameter
covariance (``sigma^2 (J^T J)^-1``, sigma from the fit residuals) through ``x = G^-1(u)``. It does not add the
noise of the point being mapped (a tracked marker's own detection noise), which depends on the detector, nor the
uncertainty of the lens intrinsics. Like the paper's map, the value is the radius that contains the true position
95% of the time (the exact quantile of the radial error of an anisotropic 2D Gaussian, not a circular bound).

Computed on a coarse pixel grid (every ``step_px``) and resized; statistics are over the pixels of the working
area, each pixel weighted equally as in the paper.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.files import Calibration
from edge.calibration.homography import PlaneFit
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]

CONFIDENCE = 0.95


@functools.cache
def _quantile_table(confidence: float = CONFIDENCE, n_ratio: int = 101) -> tuple[FloatArray, FloatArray]:
    """For eigenvalue ratios rho = l2/l1 in [0, 1]: the radius r/sqrt(l1) with P(|e| <= r) = confidence.

    P(|e| <= r) = 1/(2 pi sqrt(l1 l2)) * integral over theta of (1 - exp(-r^2 a/2)) / a, a = cos^2/l1 + sin^2/l2.
    """
    theta = (np.arange(2048) + 0.5) * (2.0 * np.pi / 2048)
    ratios = np.linspace(0.0, 1.0, n_ratio)
    radii = np.empty(n_ratio)
    for k, rho in enumerate(ratios):
        if rho == 0.0:
            radii[k] = 1.959963984540054  # one-dimensional: the 97.5% normal quantile
            continue
        a = np.cos(theta) ** 2 + np.sin(theta) ** 2 / rho
        lo, hi = 0.0, 4.0
        for _ in range(60):
            mid = (lo + hi) / 2.0
            p = np.mean((1.0 - np.exp(-0.5 * mid**2 * a)) / a) / np.sqrt(rho)
            lo, hi = (mid, hi) if p < confidence else (lo, mid)
        radii[k] = (lo + hi) / 2.0
    return ratios, radii


def radial_quantile(cov: FloatArray) -> FloatArray:
    """(N, 2, 2) covariances -> (N,) radius containing the point 95% of the time."""
    ev = np.linalg.eigvalsh(cov)  # ascending
    l1 = np.maximum(ev[:, 1], 0.0)
    l2 = np.clip(ev[:, 0], 0.0, None)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(l1 > 0, l2 / l1, 1.0)
    ratios, radii = _quantile_table()
    return np.asarray(np.sqrt(l1) * np.interp(rho, ratios, radii))


@dataclass(frozen=True)
class ErrorMap:
    """``error_cm``: (H, W) predicted 95% error per pixel (NaN where the pixel's ray misses the plane).
    ``in_area``: (H, W) bool, pixels inside the working area. ``mean_cm``, ``max_cm``: over those pixels."""

    error_cm: FloatArray
    in_area: NDArray[np.bool_]
    mean_cm: float
    max_cm: float
    sigma_px: float


def predicted_error_map(plane: PlaneFit, sigma_px: float, cal: Calibration, *, step_px: int = 8) -> ErrorMap:
    """The error map of a point-pair fit (``plane`` in ideal pixels) for the calibration ``cal`` it produced."""
    w, h = cal.image_size
    us = np.arange(0.0, w + step_px, step_px)
    vs = np.arange(0.0, h + step_px, step_px)
    gu, gv = np.meshgrid(us, vs)
    uv = np.column_stack([gu.ravel(), gv.ravel()])
    world = cal.pixel_to_world(uv)
    ok = np.all(np.isfinite(world), axis=1)
    coarse = np.full(uv.shape[0], np.nan)
    if np.any(ok):
        cov = plane.world_covariance(world[ok], sigma_px)
        coarse[ok] = radial_quantile(cov)
    grid = coarse.reshape(gv.shape)
    full = _resize_to(grid, us, vs, w, h)
    in_area = area_mask(cal)
    vals = full[in_area & np.isfinite(full)]
    if vals.size == 0:
        raise CalibrationError("the working area is not in the image: no error map")
    return ErrorMap(full, in_area, float(vals.mean()), float(vals.max()), sigma_px)


def _resize_to(grid: FloatArray, us: FloatArray, vs: FloatArray, w: int, h: int) -> FloatArray:
    """Bilinear interpolation of a grid sampled at ``us`` x ``vs`` onto every pixel centre 0..w-1, 0..h-1."""
    step_u, step_v = us[1] - us[0], vs[1] - vs[0]
    map_x, map_y = np.meshgrid(np.arange(w) / step_u, np.arange(h) / step_v)
    out = cv2.remap(
        grid.astype(np.float32),
        map_x.astype(np.float32),
        map_y.astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return np.asarray(out, dtype=np.float64)


def area_outline_px(cal: Calibration, samples_per_edge: int = 64) -> FloatArray:
    """(M, 2) the working area's outline in (distorted) pixels, densely sampled so lens curvature shows."""
    x0, y0, x1, y1 = cal.area_cm
    t = np.linspace(0.0, 1.0, samples_per_edge, endpoint=False)
    edges = [
        np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y0)]),
        np.column_stack([np.full_like(t, x1), y0 + (y1 - y0) * t]),
        np.column_stack([x1 - (x1 - x0) * t, np.full_like(t, y1)]),
        np.column_stack([np.full_like(t, x0), y1 - (y1 - y0) * t]),
    ]
    return cal.world_to_pixel(np.vstack(edges))


def area_mask(cal: Calibration) -> NDArray[np.bool_]:
    """(H, W) bool: pixels whose world point lies inside the working area."""
    w, h = cal.image_size
    mask = np.zeros((h, w), dtype=np.uint8)
    outline = area_outline_px(cal)
    cv2.fillPoly(mask, [np.round(outline * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def write_error_map_png(
    path: Path,
    emap: ErrorMap,
    cal: Calibration,
    *,
    points_uv_px: FloatArray | None = None,
    rejected_uv_px: FloatArray | None = None,
    background: NDArray[np.uint8] | None = None,
    title: str | None = None,
) -> None:
    """Write the map as a PNG with a colour scale, the working area outlined and the survey points marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = cal.image_size
    err = np.where(np.isfinite(emap.error_cm), emap.error_cm, np.nan)
    vmax = max(2.0 * emap.max_cm, 1e-6)
    fig, ax = plt.subplots(figsize=(12.8, 7.9), dpi=100)
    if background is not None:
        gray = background if background.ndim == 2 else cv2.cvtColor(background, cv2.COLOR_BGR2GRAY)
        ax.imshow(gray, cmap="gray", extent=(-0.5, w - 0.5, h - 0.5, -0.5), alpha=1.0)
    im = ax.imshow(
        err,
        cmap="magma",
        vmin=0.0,
        vmax=vmax,
        extent=(-0.5, w - 0.5, h - 0.5, -0.5),
        alpha=0.75 if background is not None else 1.0,
        interpolation="nearest",
    )
    outline = area_outline_px(cal)
    closed = np.vstack([outline, outline[:1]])
    ax.plot(closed[:, 0], closed[:, 1], color="cyan", linewidth=1.5, label="working area")
    if points_uv_px is not None and len(points_uv_px):
        ax.plot(points_uv_px[:, 0], points_uv_px[:, 1], "o", color="lime", markersize=4, label="survey points")
    if rejected_uv_px is not None and len(rejected_uv_px):
        ax.plot(rejected_uv_px[:, 0], rejected_uv_px[:, 1], "x", color="red", markersize=9, mew=2, label="rejected")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.legend(loc="lower right", fontsize=8)
    cbar = fig.colorbar(im, ax=ax, fraction=0.03, pad=0.01, extend="max")
    cbar.set_label("predicted 95% position error (cm)")
    ax.set_title(
        title
        or f"calibration error map: working area mean {emap.mean_cm:.3f} cm, max {emap.max_cm:.3f} cm "
        f"(sigma {emap.sigma_px:.2f} px)"
    )
    fig.tight_layout()
    try:
        fig.savefig(path)
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot write error map ({exc.strerror or exc})") from exc
    finally:
        plt.close(fig)
