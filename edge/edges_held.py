"""Marker edges per frame on a held edge model: the quick path of ``edge.edges_encoded``.

The full fit (:func:`edge.edges_encoded.fit_edges`: fourteen parameters by Levenberg-Marquardt, about a second per
marker) learns what does not change from frame to frame: the camera's optical blur ``sigma`` and its stream's
chroma spread ``k`` (along image u and v), and the rover's body top (its linear level relative to the marker's, so
it follows the exposure and the local light). :func:`hold` keeps the median of a few full fits. Per frame,
:func:`fit_edges_held` measures the marker's and the surround's colours from the frame (as the full fit does) and
fits per side only the edge ``u0`` and the margin ``m`` out to what lies beyond: four independent two-parameter
Gauss-Newton fits, run side by side as arrays, with analytic derivatives (the tone curve's by a central difference).

The margin is fitted per frame, not held: where a side of the body faces the camera, its visible side face lies
beyond the top and the one-step model takes both as the "margin", so the fitted margin follows the pose (the full
fits of one rover on four poses found 1.5-35 cm on the same side); held, it moved the centres by up to 0.7 cm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.edges_encoded import (
    BIN_PX,
    REACH_IN_PX,
    REACH_OUT_PX,
    YCC_FROM_BGR,
    EdgeFit,
    FloatArray,
    SideProfile,
    ToneCurve,
    beyond_level,
    bgr_of_ycc,
    phi,
    srgb_decode,
    srgb_encode,
)

MAX_SHIFT_PX = 2.5  # an edge farther than this from where the first centre puts it: not this marker's edge
MARGIN_PX = (0.3, 20.0)  # the fitted margin's range
STEPS = 8  # Gauss-Newton steps at most (it converges in 3-5)
TOLERANCE_PX = 0.005  # steps below this on every side: converged
GRID_PX = np.arange(-REACH_IN_PX + BIN_PX / 2, REACH_OUT_PX, BIN_PX)  # the bins' centres, as the full fit's


@dataclass(frozen=True)
class HeldEdges:
    """What holds between frames: the camera's ``sigma_px`` and ``k_px`` (chroma spread along image u, v), the
    rover's ``dark_rel`` (3,) (its body top's linear B, G, R over the marker's, summed over channels) and
    ``margin_cm``, the margin the fits start from."""

    sigma_px: float
    k_px: tuple[float, float]
    dark_rel: FloatArray
    margin_cm: float


def hold(fits: Sequence[EdgeFit]) -> HeldEdges:
    """The held model from full fits of the same rover and camera: the median of each parameter."""
    return HeldEdges(
        float(np.median([f.sigma_px for f in fits])),
        (float(np.median([f.k_px[0] for f in fits])), float(np.median([f.k_px[1] for f in fits]))),
        np.median([f.dark_rel for f in fits], axis=0),
        float(np.median([f.margin_cm for f in fits])),
    )


def fit_edges_held(
    profiles: list[SideProfile],
    marker_ycc: FloatArray,
    held: HeldEdges,
    decode: ToneCurve = srgb_decode,
    encode: ToneCurve = srgb_encode,
) -> EdgeFit | None:
    """The four edges (and margins) of the profiles on the ``held`` model; None when an edge is not found within
    :data:`MAX_SHIFT_PX` (the profiles are not of this marker and surround) or the fit is singular. The fit's
    ``rms`` is over all four sides (8-bit units), as the full fit's."""
    n_grid = len(GRID_PX)
    marker = decode(np.clip(bgr_of_ycc(marker_ycc), 0, 1))
    dark = held.dark_rel * float(marker.sum())
    beyond = np.array([beyond_level(p, decode) for p in profiles])  # (4, 3)
    scale = np.array([p.px_per_cm for p in profiles])
    # the measured bins on the model's grid, (4, n_grid): their values and which are measured
    target = np.zeros((4, n_grid, 3))
    measured = np.zeros((4, n_grid))
    for side, p in enumerate(profiles):
        idx = np.clip(np.round((p.u_px - GRID_PX[0]) / BIN_PX).astype(np.int64), 0, n_grid - 1)
        target[side, idx] = p.ycc
        measured[side, idx] = 1.0
    smooth = np.stack(
        [_smoothing(math.hypot(held.k_px[0] * p.normal_px[0], held.k_px[1] * p.normal_px[1])) for p in profiles]
    )
    u0 = np.zeros(4)
    margin = np.clip(held.margin_cm * scale, *MARGIN_PX)
    for _ in range(STEPS):
        residual, d_u0, d_m = _model(u0, margin, marker, dark, beyond, held.sigma_px, smooth, encode, target)
        residual *= measured[:, :, None]
        jac = np.stack([d_u0.reshape(4, -1), d_m.reshape(4, -1)], axis=2) * np.repeat(measured, 3, axis=1)[..., None]
        jac_t = jac.transpose(0, 2, 1)
        jtj = jac_t @ jac + 1e-6 * np.eye(2)
        jtr = (jac_t @ residual.reshape(4, -1, 1))[..., 0]
        if not np.all(np.linalg.det(jtj) > 0):
            return None
        step = -np.linalg.solve(jtj, jtr[..., None])[..., 0]
        step = np.clip(step, -0.5, 0.5)
        u0 += step[:, 0]
        margin = np.clip(margin + step[:, 1], *MARGIN_PX)
        if np.any(np.abs(u0) > MAX_SHIFT_PX):
            return None
        if float(np.abs(step).max()) < TOLERANCE_PX:
            break
    residual = _model(u0, margin, marker, dark, beyond, held.sigma_px, smooth, encode, target)[0]
    residual *= measured[:, :, None]
    return EdgeFit(
        u0,
        margin,
        held.sigma_px,
        held.k_px,
        float("nan"),
        math.sqrt(float(np.sum(residual * residual)) / (3.0 * measured.sum())),
        held.dark_rel,
        margin / scale,
    )


def _model(
    u0: FloatArray,
    margin: FloatArray,
    marker: FloatArray,
    dark: FloatArray,
    beyond: FloatArray,
    sigma: float,
    smooth: FloatArray,
    encode: ToneCurve,
    target: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The four sides' model minus ``target`` and its derivatives by the edge and by the margin, (4, n_grid, 3)
    each: ``edge.edges_encoded``'s model on the bins' grid, the chroma spread by the (4, n_grid, n_grid)
    ``smooth`` matrices."""
    z_a = (u0[:, None] - GRID_PX) / sigma
    z_b = (GRID_PX - u0[:, None] - margin[:, None]) / sigma
    a, b = phi(z_a)[..., None], phi(z_b)[..., None]
    pdf_a = (np.exp(-0.5 * z_a * z_a) / (sigma * math.sqrt(2.0 * math.pi)))[..., None]
    pdf_b = (np.exp(-0.5 * z_b * z_b) / (sigma * math.sqrt(2.0 * math.pi)))[..., None]
    far = beyond[:, None, :]
    lin = a * marker + (1.0 - a - b) * dark + b * far
    d_m = -pdf_b * (far - dark)  # d lin / d margin
    d_u0 = pdf_a * (marker - dark) + d_m  # d lin / d u0
    slope = 255.0 * _tone_slope(encode, lin)
    ycc = np.concatenate([255.0 * encode(lin), slope * d_u0, slope * d_m], axis=2)  # (4, n_grid, 9)
    ycc = ycc.reshape(4, -1, 3, 3) @ YCC_FROM_BGR.T
    chroma = smooth @ ycc[..., 1:].reshape(4, len(GRID_PX), 6)  # the spread of the model's and derivatives' chroma
    ycc[..., 1:] = chroma.reshape(4, -1, 3, 2)
    return ycc[:, :, 0] - target, ycc[:, :, 1], ycc[:, :, 2]


def _tone_slope(encode: ToneCurve, lin: FloatArray) -> FloatArray:
    """d encode / d lin at ``lin``: the sRGB curve's own derivative, any other curve's by a central difference."""
    if encode is srgb_encode:
        x = np.clip(lin, 1e-6, 1.0)
        return np.where(x <= 0.0031308, 12.92, (1.055 / 2.4) * x ** (1.0 / 2.4 - 1.0))
    eps = 1e-5
    return (encode(lin + eps) - encode(lin - eps)) / (2.0 * eps)


def _smoothing(k_px: float) -> FloatArray:
    """(n_grid, n_grid) the chroma spread of ``k_px`` on the bins' grid as a matrix: a Gaussian, the ends
    replicated (as ``edge.edges_encoded``'s)."""
    n_grid = len(GRID_PX)
    k_bins = max(k_px, 1e-3) / BIN_PX
    half = math.ceil(3.5 * k_bins) + 1
    offsets = np.arange(-half, half + 1)
    taps = np.exp(-0.5 * (offsets / k_bins) ** 2)
    taps /= taps.sum()
    rows = np.repeat(np.arange(n_grid), len(offsets))
    cols = np.clip(rows + np.tile(offsets, n_grid), 0, n_grid - 1)
    flat = np.bincount(rows * n_grid + cols, np.tile(taps, n_grid), minlength=n_grid * n_grid)
    return np.asarray(flat, dtype=np.float64).reshape(n_grid, n_grid)
