"""Sub-pixel coverage: the share of each pixel of a tracker window that the marker covers, by linear unmixing.

A binary mask puts a marker's edge on pixel boundaries; a far-side marker is about 21 x 9 pixels, so that is
centimetres. Each pixel near the edge is instead unmixed, in linear light, between the marker's colour and what
surrounds it (the floor, the rover's body): ``docs/tracking.md``, "Sub-pixel edges".

A marker is usually lit by one light, and its colour is one colour. Where the border of a sunlit patch or a shadow
crosses it, its part in the sun is two or three times brighter than its part in the shade: against the marker's mean
colour, an edge pixel in the shade looks little covered and one in the sun fully, and the centre moves toward the sun
(0.3-0.4 cm; 1-1.5 cm with the threshold cutting its shaded part). :func:`light_ratio` tells such a marker (its
interior's brightness spans more than :data:`TWO_LIGHTS`; under one light, compressed chroma and blur leave at most
1.33), and its edge pixels are then unmixed against the marker's colour at the brightness it has where they are
(:func:`local_mean`).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.segmentation import F32, LINEAR, U8, BoolArray, erode, linear_bgr

_CHANNEL_SUM = np.ones((1, 3), np.float32)
_CODES = np.arange(256, dtype=np.float64)
TWO_LIGHTS = 1.5  # a marker whose interior's brightness (linear light, p90 / p10) spans this is in two lights
LOCAL_LIGHT_PX = 4.0  # "where it stands": the marker's level at a pixel is the Gaussian mean of its interior this near
ON_THE_FLOOR = 0.25  # an edge pixel this near (of |marker - floor|) the line from the floor to the marker mixes the two
NEAR_PX = 3.0  # what lies beside an edge pixel: the band round the marker this near it (a Gaussian's sigma)
TAPS_MAX_PX = 160  # local_mean_at's cached taps for windows up to this long (64 of them: 6.5 MB at most)


def linear_luminance(linear: F32) -> F32:
    """(h, w) float32: the sum of an (h, w, 3) image's channels in linear light (a brightness, to any scale)."""
    return np.asarray(cv2.transform(linear, _CHANNEL_SUM), np.float32)  # a tenth of the cost of numpy's sum


def light_ratio(luminance: NDArray[np.floating], encoded: bool = False) -> float:
    """How far the brightness of a marker's interior pixels (``luminance``, linear light, any scale) spans: their
    90th over their 10th percentile; 0 with fewer than 8 pixels (nothing to tell), inf over a black 10th.
    ``encoded``: the pixels' mean 8-bit values instead (the window's ``lum``, already at hand): the two percentiles
    are taken through the tone curve (the order is the same; for one hue within a few per cent of the above)."""
    n = luminance.size
    if n < 8:
        return 0.0
    k_lo, k_hi = int(0.1 * (n - 1)), int(0.9 * (n - 1) + 0.5)  # order statistics: several times np.percentile's speed
    parted = np.partition(luminance.ravel(), (k_lo, k_hi))
    lo, hi = float(parted[k_lo]), float(parted[k_hi])
    if encoded:
        lo, hi = float(np.interp(lo, _CODES, LINEAR)), float(np.interp(hi, _CODES, LINEAR))
    return hi / lo if lo > 0 else float("inf")


def local_mean(values: F32, source: BoolArray, sigma_px: float) -> F32:
    """(h, w) float32 (or (h, w, c) for (h, w, c) ``values``, each channel): at every pixel the Gaussian-weighted
    (``sigma_px``) mean of ``values`` over the ``source`` pixels near it (a normalised convolution), drawn to their
    plain mean where none is near. Channels are blurred with their weight in one call."""
    weight = source.astype(np.float32)
    prior = np.float32(0.01)
    if values.ndim == 3:
        c = values.shape[2]
        blurred = cv2.GaussianBlur(np.dstack([values * weight[:, :, None], weight]), (0, 0), sigma_px)
        means = np.asarray(cv2.mean(values, mask=source.view(np.uint8))[:c], np.float32)
        return np.asarray((blurred[:, :, :c] + prior * means) / (blurred[:, :, c:] + prior), dtype=np.float32)
    num = cv2.GaussianBlur(values * weight, (0, 0), sigma_px)
    den = cv2.GaussianBlur(weight, (0, 0), sigma_px)
    mean = np.float32(cv2.mean(values, mask=source.view(np.uint8))[0])
    return np.asarray((num + prior * mean) / (den + prior), dtype=np.float32)


def local_mean_at(values: F32, source: BoolArray, sigma_px: float, ys: NDArray[np.intp], xs: NDArray[np.intp]) -> F32:
    """:func:`local_mean` at the pixels ``ys``, ``xs`` only: (n,) float32, or (n, c) for (h, w, c) ``values``. The
    same sums (OpenCV's kernel and its reflected border), taken at those pixels alone: a dozen edge pixels of a
    marker's window cost a third of blurring the whole window. A window longer than :data:`TAPS_MAX_PX` either way
    (a blob joined to something large) is blurred whole instead: the cached taps stay a few megabytes."""
    h, w = source.shape
    if max(h, w) > TAPS_MAX_PX:
        return local_mean(values, source, sigma_px)[ys, xs]
    c = values.shape[2] if values.ndim == 3 else 1
    weight = source.astype(np.float32)
    rows = _taps(h, sigma_px)[ys]  # (n, h): each pixel's vertical pass, as one row of weights over the window's rows
    cols = _taps(w, sigma_px)[xs][:, None, :]  # (n, 1, w): and its horizontal pass
    weighted = values * (weight[:, :, None] if values.ndim == 3 else weight)
    num = np.matmul(cols, (rows @ weighted.reshape(h, w * c)).reshape(-1, w, c))[:, 0]
    den = np.matmul(cols, (rows @ weight)[:, :, None])[:, 0]
    means = np.asarray(cv2.mean(values, mask=source.view(np.uint8))[:c], np.float32)
    prior = np.float32(0.01)
    mean = (num + prior * means) / (den + prior)
    return np.asarray(mean if values.ndim == 3 else mean[:, 0], dtype=np.float32)


@lru_cache(maxsize=64)  # window lengths seen: a marker's crop, 20-150 px
def _taps(length: int, sigma_px: float) -> F32:
    """(length, length) float32: row ``i`` holds the weights cv2.GaussianBlur (``sigma_px``, its own kernel size
    for float images) gives each of ``length`` samples at sample ``i``, the border reflected as it reflects it
    (BORDER_REFLECT_101, again and again where the kernel is longer than the samples). Read-only (cached)."""
    size = round(sigma_px * 8 + 1) | 1
    kernel = cv2.getGaussianKernel(size, sigma_px, cv2.CV_32F)[:, 0].astype(np.float64)
    at = np.arange(length)[:, None] + (np.arange(size) - size // 2)
    if length > 1:
        period = 2 * (length - 1)
        at %= period
        at = np.where(at >= length, period - at, at)
    else:
        at[:] = 0
    taps = np.zeros((length, length))
    np.add.at(taps, (np.repeat(np.arange(length), size), at.ravel()), np.tile(kernel, length))
    out = taps.astype(np.float32)
    out.flags.writeable = False
    return out


def marker_level(plane_roi: F32, core: BoolArray, interior: BoolArray | None = None) -> float:
    """The marker's value in its colour plane: the mean over the core's interior (its edge pixels are mixed).
    ``interior``: ``erode(core, 1)`` when the caller has it already."""
    pick = erode(core, 1) if interior is None else interior
    if not np.count_nonzero(pick):  # count_nonzero: a quarter of the cost of any() on a window
        pick = core
        if not np.count_nonzero(pick):
            return 0.0
    return float(cv2.mean(plane_roi, mask=pick.view(np.uint8))[0])


def coverage_weights(
    bgr_roi: U8,
    core: BoolArray,
    ring_px: int,
    exclude: BoolArray | None = None,
    pure: BoolArray | None = None,
    linear: F32 | None = None,
    interior: BoolArray | None = None,
    apart: BoolArray | None = None,
    floor_mixes: bool = True,
) -> F32:
    """(h, w) float32 share of each pixel covered by the marker whose filled binary mask is ``core``.

    Pixels of the core's interior are fully covered (1, even under a glare spot that hole filling closed). A pixel
    within ``ring_px`` of the core's edge sees a mix of the marker ``M`` and what surrounds it: the bright floor
    ``F`` or the dark rover body ``D``. In *linear* light (the camera's tone curve undone: light mixes linearly,
    8-bit values do not) its colour is ``p = a M + b F + (1 - a - b) D``, so three colour channels give the
    marker's share ``a`` by least squares (linear unmixing). ``M`` is the mean of the interior's ``pure`` pixels
    (glare excluded), ``D`` and ``F`` the means of the darker and brighter halves of a band just outside the ring.
    Shares below 0 are kept (down to -0.5) so noise on background pixels averages out instead of biasing.
    ``exclude``: ring pixels that may be something else (of another rover's hue), given no share unless they are
    the marker mixed with what lies beside them (``floor_mixes``, :func:`on_the_floor`); ``apart``: pixels
    of other things (another rover's marker), left out of the band ``D`` and ``F`` come from; ``linear``:
    ``linear_bgr(bgr_roi)`` when the caller has it already (else only the part near the core is linearised);
    ``interior``: ``erode(core, 1)`` when the caller has it already.

    Unmixed in the camera's 8-bit values instead, a pixel half covered by the black body looked 73 % marker: the
    edge moved out on the dark side (towards the camera, where the body's side shows), by 0.4 cm with a 1.2 px blur.
    The outline fit (``edge.outline``) refines the centre further; these shares give the area and its start.
    """
    full = core.astype(np.float32)
    box = reach_box(core, ring_px)  # everything below happens within it
    if box is None:
        return full
    rows, cols = box
    # the crop in linear light (contiguous: cv2 would copy it); the look-up table is per pixel, so of the crop alone
    lin = linear_bgr(bgr_roi[rows, cols]) if linear is None else np.ascontiguousarray(linear[rows, cols])
    weights = _unmix(
        lin,
        np.ascontiguousarray(core[rows, cols]),
        ring_px,
        None if exclude is None else exclude[rows, cols],
        None if pure is None else pure[rows, cols],
        None if interior is None else interior[rows, cols],  # erosion of the crop: the same pixels (see _unmix)
        None if apart is None else apart[rows, cols],
        floor_mixes,
    )
    if weights is not None:
        full[rows, cols] = weights
    return full


def reach_box(core: BoolArray, ring_px: int) -> tuple[slice, slice] | None:
    """The rows and columns of the window :func:`coverage_weights` reads for the marker ``core``: its bounding box
    grown by the outer band's reach (``ring_px + 3``); None for an empty core."""
    x, y, w, h = cv2.boundingRect(core.view(np.uint8))
    if w == 0 or h == 0:
        return None
    reach = ring_px + 3
    return slice(max(0, y - reach), min(core.shape[0], y + h + reach)), slice(
        max(0, x - reach), min(core.shape[1], x + w + reach)
    )


def _unmix(
    lin: F32,
    core: BoolArray,
    ring_px: int,
    exclude: BoolArray | None,
    pure: BoolArray | None,
    interior: BoolArray | None = None,
    apart: BoolArray | None = None,
    floor_mixes: bool = True,
) -> F32 | None:
    """:func:`coverage_weights` on a crop that holds the core's outer band (``lin``: the crop in linear light;
    ``interior``: ``erode(core, 1)``, of the crop or cropped from a larger one: the crop ends at least the outer
    band's reach from the core or where the larger image ends, so the two are the same); None where the marker
    cannot be told from its surround (the binary core stands)."""
    # The chessboard distance to the core gives both its dilations (by ring_px and by ring_px + 3) in one pass.
    # Masks of booleans: ``a > b`` is ``a & ~b`` in one pass.
    dist = cv2.distanceTransform((~core).view(np.uint8), cv2.DIST_C, 3)
    region = dist <= ring_px
    outer = (dist <= ring_px + 3) > region
    others = None
    if exclude is not None:
        others = region & (exclude > core)
        region = region > others  # region & (~exclude | core)
    if apart is not None:
        outer = outer > apart
    if interior is None:
        interior = erode(core, 1)
    if not np.count_nonzero(interior):  # count_nonzero: a quarter of the cost of any() on a crop
        interior = core
    if np.count_nonzero(outer) < 4:
        return None
    sample = interior & pure if pure is not None else interior
    source = sample if np.count_nonzero(sample) else interior  # the marker's pure colour: glare left out
    marker = _mean(lin, source)
    lum = linear_luminance(lin)
    lum_outer = lum[outer]
    half = lum_outer.size // 2
    lum_outer.partition(half)  # in place: a fresh array
    cut = lum_outer[half]
    dark = _mean(lin, outer & (lum <= cut))
    bright = _mean(lin, outer & (lum >= cut))
    # Three channels: plain floats, several times quicker than arrays this small.
    a0, a1, a2 = marker[0] - dark[0], marker[1] - dark[1], marker[2] - dark[2]
    b0, b1, b2 = bright[0] - dark[0], bright[1] - dark[1], bright[2] - dark[2]
    aa, ab = a0 * a0 + a1 * a1 + a2 * a2, a0 * b0 + a1 * b1 + a2 * b2
    bb = b0 * b0 + b1 * b1 + b2 * b2 + 1e-3 * aa  # ridge: floor and body alike (no floor in view) is not singular
    det = aa * bb - ab * ab
    if aa <= 1e-6 or det <= 1e-14:
        return None
    # share = (p - D) . (a bb - b ab) / det for every pixel at once: one affine map of the three channels
    r0, r1, r2 = (a0 * bb - b0 * ab) / det, (a1 * bb - b1 * ab) / det, (a2 * bb - b2 * ab) / det
    ring = region > interior
    out = interior.astype(np.float32)  # the ring unmixed below, the interior whole (1.0), the rest nothing
    deep = erode(interior, 1)
    if floor_mixes and others is not None and np.count_nonzero(others):
        on_the_floor(out, others > interior, lin, marker, outer)  # the band beyond the ring: what lies beside
    if light_ratio(lum[deep]) >= TWO_LIGHTS:
        _unmix_in_two_lights(out, lin, lum, ring, source, marker, dark, bright)
        return out
    affine = np.array([[r0, r1, r2, -(dark[0] * r0 + dark[1] * r1 + dark[2] * r2)]], np.float32)
    share = cv2.transform(lin, affine)
    np.minimum(np.maximum(share, -0.5, out=share), 1.0, out=share)  # clipped in place (np.clip's wrapper costs more)
    np.copyto(out, share, where=ring)  # cheaper than np.where, which would promote the booleans
    return out


def on_the_floor(out: F32, pixels: BoolArray, lin: F32, marker: tuple[float, float, float], band: BoolArray) -> None:
    """Give those of ``pixels`` (edge pixels of another rover's hue) that are the marker mixed with what lies beside
    them their share of it, into ``out``: in linear light (``lin``), a pixel ``p`` on the line from the colour
    beside it ``B`` to the ``marker``'s ``M``, within :data:`ON_THE_FLOOR` of ``|M - B|`` of it and between the
    two, is ``a M + (1 - a) B``; the rest keep theirs. ``B`` is the Gaussian mean (sigma :data:`NEAR_PX`) of the
    ``band`` pixels near it (the band round the marker, beyond its ring): the floor beyond a far edge, the body beside a
    near one.

    The hue classes split a marker's mixed edge pixels by hue: against warm wood a purple marker's are magenta, and
    left out as another rover's they took 0.5-1 px off its far edge (1.35 cm toward the camera at the far side).
    Another rover's marker is not on that line (it is more saturated than any mix of this marker with the floor;
    its saturated pixels are not in the band). What lies beside is read from the window, not from the background
    model's reference: the model knows no floor round a rover that has stood where it stood at the first frame (a
    third of the windows of a clip's first four seconds had none), and a centre that moved as the model learned
    the floor moved the offsets learned from it (``edge.centre_offsets``). Near each pixel, not the band's mean: the
    floor beyond one edge, the body beside another, a sunlit patch's border."""
    if not np.count_nonzero(pixels):
        return
    ys, xs = np.nonzero(pixels)
    b = local_mean_at(lin, band, NEAR_PX, ys, xs)
    q = lin[ys, xs] - b  # (n, 3): the pixels and the marker, less what lies beside them
    d = np.asarray(marker, np.float32) - b
    dd, qd = (d * d).sum(axis=1), (q * d).sum(axis=1)
    share = qd / np.maximum(dd, 1e-9)
    off = (q * q).sum(axis=1) - share * qd  # |q - share d|^2
    ok = (off <= ON_THE_FLOOR**2 * dd) & (share > -0.1) & (share < 1.1) & (dd > 1e-4)
    out[ys[ok], xs[ok]] = np.minimum(np.maximum(share[ok], 0.0), 1.0)  # np.clip's wrapper costs more


def _unmix_in_two_lights(
    out: F32,
    lin: F32,
    lum: F32,
    ring: BoolArray,
    source: BoolArray,
    marker: tuple[float, float, float],
    dark: tuple[float, float, float],
    bright: tuple[float, float, float],
) -> None:
    """:func:`_unmix`'s shares for the ``ring`` pixels (into ``out``) of a marker in two lights: each unmixed
    against the marker's colour scaled to the brightness its interior (``source``) has near it."""
    ys, xs = np.nonzero(ring)
    m = np.asarray(marker, np.float32)
    scale = local_mean_at(lum, source, LOCAL_LIGHT_PX, ys, xs) / np.float32(max(float(m.sum()), 1e-6))
    d = np.asarray(dark, np.float32)
    b = np.asarray(bright, np.float32) - d
    a = np.clip(scale, 0.25, 4.0)[:, None] * m - d  # the marker's colour there, less the body's
    q = lin[ys, xs] - d
    aa = (a * a).sum(axis=1)
    ab = a @ b
    bb = float(b @ b) + 1e-3 * aa  # ridge, as in _unmix
    det = aa * bb - ab * ab
    ok = (aa > 1e-6) & (det > 1e-14)
    share = ((q * a).sum(axis=1) * bb - (q @ b) * ab) / np.where(ok, det, 1.0)
    out[ys, xs] = np.where(ok, np.clip(share, -0.5, 1.0), out[ys, xs])


def _mean(values: F32, mask: BoolArray) -> tuple[float, float, float]:
    """The mean of the masked pixels of an (h, w, 3) image, per channel."""
    b, g, r, _ = cv2.mean(values, mask=mask.view(np.uint8))  # zeros for an empty mask
    return b, g, r
