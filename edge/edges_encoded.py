"""Marker edges measured in the camera's encoded chroma: a 1D edge model fitted per side of the marker.

The default centre (``edge.coverage``) unmixes each pixel in linear light. A stream's chroma spread (4:2:0, coarse
chroma quantisation) moves the marker's chroma onto its neighbours in the camera's *encoded* values; linearised,
what lands on the bright floor counts far more than what lands on the dark body, so the centre moves. Here the
edges are measured where the spread happened, in the decoded Y'CbCr (BT.601), and the spread is part of the model:
across each side of the marker (``u``: pixels along the side's outward normal on the marker plane; the pixels of
the side's middle binned by ``u`` in quarter-pixel bins, so every sub-block phase of the stream averages in) the
linear light is the marker ``M``, then the body's top ``D`` out to a margin ``m``, then what lies beyond ``F`` (floor
or the body's visible side), each step blurred by the optics ``sigma``:

    L(u) = M Phi((u0 - u)/sigma) + D (Phi((u - u0)/sigma) - Phi((u - u0 - m)/sigma)) + F Phi((u - u0 - m)/sigma)

encoded through the tone curve; the luma Y' (full resolution in every stream) is that, the chroma that convolved
with a Gaussian of ``k`` pixels (the stream's spread). ``u0``, ``m`` per side and ``sigma``, ``k``, ``D``'s level
are fitted to the four profiles at once (Levenberg-Marquardt); the centre is the middle of opposite edges.
``edge.edges_held`` fits only the edges and margins per frame, the rest held from a few of these fits.

Where the camera may sharpen (``weigh_channels``), the luma and the chroma are weighed by how well the model
describes each. A webcam sharpens its luma (an unsharp mask on the encoded luma, which leaves the chroma as it was);
that is not in the model, and beside a dark body's wall (one side dark, its opposite the floor) it moves the fitted
centre towards the camera by 0.1-0.2 cm. So the fit is made twice: once with both weighed alike, then again from
there with the luma weighed by the chroma's residual RMS over its own (a feasible weighted least squares). Where
the camera is known not to sharpen, the first fit alone: there a coarse stream's chroma misleads more than its
residual shows (4:2:0 q75, a green marker standing still: 0.07 -> 0.16 cm with the second fit).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
ToneCurve = Callable[[FloatArray], FloatArray]

BIN_PX = 0.25
REACH_IN_PX = 4.0
REACH_OUT_PX = 7.0
BAND_PX = (5.5, 7.0)  # the surround beyond the spread, relative to the edge
INNER_PX = 2.5  # bins this far inside a side are the marker's own light there (the optics' blur is <= 1.2 px)
SIDE_MIDDLE = 0.7  # the share of each side's length that counts (corners mix two sides)
FD_STEP = 1e-4  # the forward differences' step in every parameter
RESIDUAL_FLOOR = 0.5  # added to each residual RMS before weighing by it (8-bit units: rounding alone gives 0.29)
# BT.601 full range, as JPEG decodes (rows: Y', Cb, Cr; columns B', G', R')
YCC_FROM_BGR = np.array(
    [[0.114, 0.587, 0.299], [0.5, -0.331264, -0.168736], [-0.081312, -0.418688, 0.5]], dtype=np.float64
)


def srgb_decode(v: FloatArray) -> FloatArray:
    """Encoded (0..1) -> linear light through the sRGB curve."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def srgb_encode(x: FloatArray) -> FloatArray:
    """Linear light -> encoded (0..1) through the sRGB curve."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def phi(z: FloatArray) -> FloatArray:
    """The standard normal CDF, elementwise (Abramowitz and Stegun 7.1.26 for erf: within 1.5e-7)."""
    x = np.asarray(z, dtype=np.float64) / math.sqrt(2.0)
    t = 1.0 / (1.0 + 0.3275911 * np.abs(x))
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    erf = 1.0 - poly * np.exp(-x * x)
    return np.asarray(0.5 * (1.0 + np.sign(x) * erf))


@dataclass(frozen=True)
class SideProfile:
    """One side's profile: ``u_px`` (n,) bin centres along the outward normal (0: the assumed edge), ``ycc`` (n, 3)
    mean decoded Y'CbCr per bin (8-bit units), ``px_per_cm`` the normal's scale on the plane, ``normal_px`` its unit
    direction in the image (u, v): a stream that spreads its chroma along image rows only (4:2:2) spreads a side by
    how far its normal lies along them."""

    u_px: FloatArray
    ycc: FloatArray
    px_per_cm: float
    normal_px: tuple[float, float]


def side_profiles(
    bgr: NDArray[np.uint8],
    xy_cm: FloatArray,
    centre_cm: tuple[float, float],
    theta_rad: float,
    half_cm: tuple[float, float],
) -> list[SideProfile]:
    """The four sides' profiles (+x, -x, +y, -y of the marker's frame) of the marker at ``centre_cm`` with axis
    ``theta_rad`` and half sizes ``half_cm``; ``bgr`` (h, w, 3) decoded frame window, ``xy_cm`` (2, h, w) each
    pixel's centre on the marker plane."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    dx, dy = xy_cm[0] - centre_cm[0], xy_cm[1] - centre_cm[1]
    along, across = dx * c + dy * s, -dx * s + dy * c
    h, w = bgr.shape[:2]
    mid_v, mid_u = h // 2, w // 2
    # d(plane)/d(pixel) near the window's middle: the pixels per cm along each of the marker's axes
    jac = np.array(
        [
            [xy_cm[0, mid_v, mid_u + 1] - xy_cm[0, mid_v, mid_u], xy_cm[0, mid_v + 1, mid_u] - xy_cm[0, mid_v, mid_u]],
            [xy_cm[1, mid_v, mid_u + 1] - xy_cm[1, mid_v, mid_u], xy_cm[1, mid_v + 1, mid_u] - xy_cm[1, mid_v, mid_u]],
        ]
    )
    inv = np.linalg.inv(jac)
    nbins = round((REACH_IN_PX + REACH_OUT_PX) / BIN_PX)
    # each side's pixels and their bins (side * nbins + bin; a pixel may serve two sides), then one bincount per
    # channel over all four sides
    pixels, bins = [], []
    scales, normals = [], []
    for side, (normal_coord, tangent_coord, sign, half_n, half_t, n_vec) in enumerate(
        (
            (along, across, 1.0, half_cm[0], half_cm[1], (c, s)),
            (along, across, -1.0, half_cm[0], half_cm[1], (-c, -s)),
            (across, along, 1.0, half_cm[1], half_cm[0], (-s, c)),
            (across, along, -1.0, half_cm[1], half_cm[0], (s, -c)),
        )
    ):
        in_image = inv @ np.array(n_vec)
        px_per_cm = float(np.hypot(*in_image))
        u_px = (sign * normal_coord - half_n) * px_per_cm
        keep = (np.abs(tangent_coord) < SIDE_MIDDLE * half_t) & (u_px > -REACH_IN_PX) & (u_px < REACH_OUT_PX)
        pixels.append(np.flatnonzero(keep))
        bins.append(side * nbins + np.floor((u_px[keep] + REACH_IN_PX) / BIN_PX).astype(np.int64))
        scales.append(px_per_cm)
        normals.append((float(in_image[0]) / px_per_cm, float(in_image[1]) / px_per_cm))
    idx = np.concatenate(bins)
    ycc = bgr.reshape(-1, 3)[np.concatenate(pixels)].astype(np.float64) @ YCC_FROM_BGR.T
    count = np.bincount(idx, minlength=4 * nbins)[: 4 * nbins].reshape(4, nbins)
    sums = np.stack([np.bincount(idx, ycc[:, j], minlength=4 * nbins)[: 4 * nbins] for j in range(3)], 1)
    sums = sums.reshape(4, nbins, 3)
    centres: FloatArray = -REACH_IN_PX + (np.arange(nbins, dtype=np.float64) + 0.5) * BIN_PX
    profiles = []
    for side in range(4):
        good = count[side] > 0
        means: FloatArray = sums[side, good] / count[side, good, None]
        profiles.append(SideProfile(centres[good], means, scales[side], normals[side]))
    return profiles


def has_band(profile: SideProfile) -> bool:
    """Whether the profile reaches the band beyond the spread and starts inside the marker."""
    band = (profile.u_px > BAND_PX[0]) & (profile.u_px < BAND_PX[1])
    return bool(np.count_nonzero(band) >= 2 and profile.u_px[0] < -1.0)


def bgr_of_ycc(ycc: FloatArray) -> FloatArray:
    """(..., 3) Y'CbCr (8-bit units) -> B'G'R' (0..1)."""
    return np.asarray(ycc @ np.linalg.inv(YCC_FROM_BGR).T / 255.0)


def beyond_level(profile: SideProfile, decode: ToneCurve) -> FloatArray:
    """(3,) linear B, G, R of what lies beyond the side's spread: the profile's mean over :data:`BAND_PX`."""
    band = (profile.u_px > BAND_PX[0]) & (profile.u_px < BAND_PX[1])
    return decode(np.clip(bgr_of_ycc(profile.ycc[band].mean(axis=0)), 0, 1))


def _gauss_smooth(values: FloatArray, k_px: float, step_px: float = BIN_PX) -> FloatArray:
    """(n, c) values on a grid of ``step_px`` convolved with a Gaussian of ``k_px`` (edges padded by replication)."""
    k_bins = max(k_px, 1e-3) / step_px
    half = math.ceil(3.5 * k_bins) + 1
    taps = np.exp(-0.5 * (np.arange(-half, half + 1) / k_bins) ** 2)
    taps /= taps.sum()
    padded = np.concatenate([np.repeat(values[:1], half, 0), values, np.repeat(values[-1:], half, 0)])
    return np.stack([np.convolve(padded[:, j], taps, mode="valid") for j in range(values.shape[1])], 1)


@dataclass(frozen=True)
class EdgeFit:
    """The fit: ``u0_px`` (4,) edge of each side along its normal relative to the assumed one; ``margin_px`` (4,),
    ``sigma_px``, ``k_px`` the chroma's spread along image u and v, ``dark`` (the body top's level relative to the
    brightest surround), the residual RMS (8-bit units); for holding them (``edge.edges_held``): ``dark_rel`` (3,)
    the body top's linear B, G, R over the marker's (summed over channels) and ``margin_cm`` the median margin on
    the plane."""

    u0_px: FloatArray
    margin_px: FloatArray
    sigma_px: float
    k_px: tuple[float, float]
    dark: float
    rms: float
    dark_rel: FloatArray
    margin_cm: float


def _grid_index(u_px: FloatArray, grid_u: FloatArray) -> NDArray[np.int64]:
    """(n,) the regular ``grid_u``'s bin of each of a side's bins ``u_px``."""
    return np.clip(np.round((u_px - grid_u[0]) / BIN_PX).astype(np.int64), 0, len(grid_u) - 1)


def _side_model(
    idx: NDArray[np.int64],
    grid_u: FloatArray,
    marker: FloatArray,
    dark: FloatArray,
    beyond: FloatArray,
    u0: float,
    margin: float,
    sigma: float,
    k_px: float,
    encode: ToneCurve,
) -> FloatArray:
    """(n, 3) model Y'CbCr at a side's bins (evaluated on the regular ``grid_u`` and read off at its bins ``idx``,
    :func:`_grid_index`)."""
    full = profile_model(grid_u - u0, marker, dark, beyond, _bounded(margin, 20.0), sigma, k_px, encode)
    return full[idx]


def profile_model(
    u_px: FloatArray,
    marker: FloatArray,
    dark: FloatArray,
    beyond: FloatArray,
    margin: float,
    sigma: float,
    k_px: float,
    encode: ToneCurve,
) -> FloatArray:
    """(n, 3) the model's Y'CbCr (8-bit units) with the edge at 0 on the regular grid ``u_px`` (its step the
    chroma spread's unit): the module docstring's ``L(u)`` encoded, its chroma spread by ``k_px``."""
    a, b = phi(np.stack([-u_px / sigma, (u_px - margin) / sigma]))  # one call: the same values, half the overhead
    lin = a[:, None] * marker + (1.0 - a - b)[:, None] * dark + b[:, None] * beyond
    ycc = (255.0 * encode(lin)) @ YCC_FROM_BGR.T
    chroma = _gauss_smooth(ycc[:, 1:], k_px, float(u_px[1] - u_px[0]))
    return np.column_stack([ycc[:, :1], chroma])


def fit_edges(
    profiles: list[SideProfile],
    marker_ycc: FloatArray,
    decode: ToneCurve = srgb_decode,
    encode: ToneCurve = srgb_encode,
    iterations: int = 25,
    side_levels: bool = False,
    weigh_channels: bool = False,
) -> EdgeFit:
    """Fit the model of the module docstring to the four profiles (``marker_ycc``: the interior's mean Y'CbCr);
    ``weigh_channels``: fitted again with the luma weighed by the first fit's residuals (the module docstring).

    ``side_levels``: the marker's light per side scaled by its luma just inside that side (bins :data:`INNER_PX`
    in) over the interior's: a marker under a gradient of light (vignetting, a lamp's fall-off, a sunlit patch's
    border) is darker at one side than its mean, which would read as that edge moved in."""
    marker = decode(np.clip(bgr_of_ycc(marker_ycc), 0, 1))
    markers = [marker] * len(profiles)
    if side_levels:
        mid = float(decode(np.full(1, marker_ycc[0] / 255.0))[0])
        markers = []
        for p in profiles:
            inner = p.u_px <= -INNER_PX
            level = float(decode(np.full(1, p.ycc[inner, 0].mean() / 255.0))[0]) if inner.any() else mid
            markers.append(marker * (level / mid if mid > 0 else 1.0))
    beyond = [beyond_level(p, decode) for p in profiles]
    brightest = max(beyond, key=lambda v: float(v.sum()))
    grid_u = np.arange(-REACH_IN_PX + BIN_PX / 2, REACH_OUT_PX, BIN_PX)
    weights = np.ones(3)  # luma, Cb, Cr: alike in the first fit
    bins = [_grid_index(p.u_px, grid_u) for p in profiles]

    def side(j: int, x: FloatArray) -> FloatArray:
        sigma, k_u, k_v, dark = 0.05 + _bounded(x[0], 3.0), _bounded(x[1], 3.0), _bounded(x[13], 3.0), np.abs(x[2:5])
        p = profiles[j]
        k_px = math.hypot(k_u * p.normal_px[0], k_v * p.normal_px[1])
        model = _side_model(bins[j], grid_u, markers[j], dark, beyond[j], x[5 + j], x[9 + j], sigma, k_px, encode)
        return ((model - p.ycc) * weights).ravel()

    def residuals(x: FloatArray) -> FloatArray:
        return np.concatenate([side(j, x) for j in range(len(profiles))])

    # x: sigma, k along u, the body's top (3), the edges (4), the margins (4), k along v. A side's edge and margin
    # move only its own residuals: their Jacobian columns need that side alone (the same forward differences).
    ends = np.cumsum([0] + [3 * len(p.u_px) for p in profiles])
    own = {5 + j: j for j in range(len(profiles))} | {9 + j: j for j in range(len(profiles))}

    def jacobian(x: FloatArray, r: FloatArray) -> FloatArray:
        jac = np.zeros((r.size, x.size))
        for i in range(x.size):
            step = np.zeros_like(x)
            step[i] = FD_STEP
            j = own.get(i)
            if j is None:
                jac[:, i] = (residuals(x + step) - r) / FD_STEP
            else:
                jac[ends[j] : ends[j + 1], i] = (side(j, x + step) - r[ends[j] : ends[j + 1]]) / FD_STEP
        return jac

    # two starts, the body's top dark or light (the fit does not cross between them reliably)
    starts = [np.array([0.8, 0.8, *(level * brightest), 0, 0, 0, 0, 1, 1, 1, 1, 0.8]) for level in (0.05, 0.6)]
    fits = [_levenberg_marquardt(residuals, start, iterations, jacobian) for start in starts]
    x, r, cost = min(fits, key=lambda f: f[2] if math.isfinite(f[2]) else math.inf)
    if weigh_channels and math.isfinite(cost):
        weights[0] = luma_weight(r)
        x, r, cost = _levenberg_marquardt(residuals, x, iterations, jacobian)
        weights[0] = 1.0
        r = residuals(x)  # the fit's RMS on the profiles' own scale, as the first fit's
        cost = float(r @ r)
    return EdgeFit(
        x[5:9].copy(),
        np.array([_bounded(m, 20.0) for m in x[9:13]]),
        0.05 + _bounded(x[0], 3.0),
        (_bounded(x[1], 3.0), _bounded(x[13], 3.0)),
        float(np.abs(x[2:5]).sum() / brightest.sum()),
        math.sqrt(cost / r.size),
        np.abs(x[2:5]) / float(marker.sum()),
        float(np.median([_bounded(m, 20.0) / p.px_per_cm for m, p in zip(x[9:13], profiles, strict=True)])),
    )


def luma_weight(residuals: FloatArray) -> float:
    """The luma's weight from the residuals (Y', Cb, Cr interleaved, weighed alike) of a first fit: the chroma's RMS
    over the luma's, each with :data:`RESIDUAL_FLOOR` added (the module docstring's second fit)."""
    rms = np.sqrt(np.mean(residuals.reshape(-1, 3) ** 2, axis=0)) + RESIDUAL_FLOOR
    return float(math.sqrt((rms[1] ** 2 + rms[2] ** 2) / 2.0) / rms[0])


def _bounded(value: float, limit: float) -> float:
    """``|value|`` for small values, smoothly saturating at ``limit`` (keeps the fit's widths in range without the
    flat gradient of a clip, from which it would not come back)."""
    return limit * (1.0 - math.exp(-abs(float(value)) / limit))


def _levenberg_marquardt(
    fun: ToneCurve,
    x: FloatArray,
    iterations: int,
    jacobian: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """Minimise the sum of squares of ``fun(x)`` from ``x`` (``jacobian(x, fun(x))``, by default forward
    differences of ``fun`` with a step of :data:`FD_STEP`)."""
    lam = 1e-2
    r = fun(x)
    cost = float(r @ r)
    for _ in range(iterations):
        if jacobian is not None:
            jac = jacobian(x, r)
        else:
            jac = np.empty((r.size, x.size))
            for i in range(x.size):
                step = np.zeros_like(x)
                step[i] = FD_STEP
                jac[:, i] = (fun(x + step) - r) / FD_STEP
        jtj, jtr = jac.T @ jac, jac.T @ r
        delta = np.zeros_like(x)
        while lam <= 1e8:
            delta = np.asarray(np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-9), -jtr), np.float64)
            r_trial = fun(x + delta)
            c_trial = float(r_trial @ r_trial)
            if c_trial < cost:  # False for NaN
                x, r, cost, lam = x + delta, r_trial, c_trial, lam * 0.3
                break
            lam *= 10.0
        if lam > 1e8 or float(np.abs(delta).max()) < 1e-4:
            break
    return x, r, cost


def encoded_edge_centre(
    bgr: NDArray[np.uint8],
    xy_cm: FloatArray,
    interior: NDArray[np.bool_],
    centre_cm: tuple[float, float],
    theta_rad: float,
    size_cm: tuple[float, float],
    side_levels: bool = False,
    weigh_channels: bool = False,
) -> tuple[tuple[float, float], EdgeFit] | None:
    """The marker's centre on the plane from its four fitted edges, and the fit; None when the window does not hold
    every side's profile out to the band beyond the spread (:data:`BAND_PX`).

    ``bgr`` (h, w, 3) the decoded window, ``xy_cm`` (2, h, w) its pixels' centres on the marker plane,
    ``interior`` (h, w) pixels well inside the marker (its colour), ``centre_cm`` and ``theta_rad`` a first centre
    and the marker's long axis (the sides are sampled around them), ``size_cm`` the marker's length and width. Each
    edge is found along its own normal on the plane, so the centre is the middle of opposite edges on the plane, not
    in the image. ``side_levels``, ``weigh_channels``: as :func:`fit_edges`."""
    profiles = side_profiles(bgr, xy_cm, centre_cm, theta_rad, (size_cm[0] / 2, size_cm[1] / 2))
    if not all(has_band(p) for p in profiles):
        return None
    marker_ycc = bgr[interior].astype(np.float64).mean(axis=0) @ YCC_FROM_BGR.T
    fit = fit_edges(profiles, marker_ycc, side_levels=side_levels, weigh_channels=weigh_channels)
    return edge_midpoint(centre_cm, theta_rad, fit.u0_px, profiles), fit


def edge_midpoint(
    centre_cm: tuple[float, float], theta_rad: float, u0_px: FloatArray | list[float], profiles: list[SideProfile]
) -> tuple[float, float]:
    """The centre moved to the middle of the edges ``u0_px`` (+x, -x, +y, -y sides, pixels along each normal)."""
    cm = [u / p.px_per_cm for u, p in zip(u0_px, profiles, strict=True)]
    a, b = (cm[0] - cm[1]) / 2, (cm[2] - cm[3]) / 2
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    return centre_cm[0] + c * a - s * b, centre_cm[1] + s * a + c * b
