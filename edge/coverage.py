"""Sub-pixel coverage: the share of each pixel of a tracker window that the marker covers, by linear unmixing.

A binary mask puts a marker's edge on pixel boundaries; a far-side marker is about 21 x 9 pixels, so that is
centimetres. Each pixel near the edge is instead unmixed, in linear light, between the marker's colour and what
surrounds it (the floor, the rover's body): ``docs/tracking.md``, "Sub-pixel edges".
"""

from __future__ import annotations

import cv2
import numpy as np

from edge.segmentation import F32, U8, BoolArray, erode, linear_bgr

_CHANNEL_SUM = np.ones((1, 3), np.float32)


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
) -> F32:
    """(h, w) float32 share of each pixel covered by the marker whose filled binary mask is ``core``.

    Pixels of the core's interior are fully covered (1, even under a glare spot that hole filling closed). A pixel
    within ``ring_px`` of the core's edge sees a mix of the marker ``M`` and what surrounds it: the bright floor
    ``F`` or the dark rover body ``D``. In *linear* light (the camera's tone curve undone: light mixes linearly,
    8-bit values do not) its colour is ``p = a M + b F + (1 - a - b) D``, so three colour channels give the
    marker's share ``a`` by least squares (linear unmixing). ``M`` is the mean of the interior's ``pure`` pixels
    (glare excluded), ``D`` and ``F`` the means of the darker and brighter halves of a band just outside the ring.
    Shares below 0 are kept (down to -0.5) so noise on background pixels averages out instead of biasing.
    ``exclude``: pixels of something else (another rover's marker); ``linear``: ``linear_bgr(bgr_roi)`` when the
    caller has it already (else only the part near the core is linearised); ``interior``: ``erode(core, 1)`` when
    the caller has it already.

    Unmixed in the camera's 8-bit values instead, a pixel half covered by the black body looked 73 % marker: the
    edge moved out on the dark side (towards the camera, where the body's side shows), by 0.4 cm with a 1.2 px blur.
    The outline fit (``edge.outline``) refines the centre further; these shares give the area and its start.
    """
    full = core.astype(np.float32)
    # Everything below happens within the outer band's reach of the core: its bounding box, grown by that much.
    x, y, w, h = cv2.boundingRect(core.view(np.uint8))
    if w == 0 or h == 0:
        return full
    reach = ring_px + 3
    rows = slice(max(0, y - reach), min(core.shape[0], y + h + reach))
    cols = slice(max(0, x - reach), min(core.shape[1], x + w + reach))
    # the crop in linear light (contiguous: cv2 would copy it); the look-up table is per pixel, so of the crop alone
    lin = linear_bgr(bgr_roi[rows, cols]) if linear is None else np.ascontiguousarray(linear[rows, cols])
    weights = _unmix(
        lin,
        np.ascontiguousarray(core[rows, cols]),
        ring_px,
        None if exclude is None else exclude[rows, cols],
        None if pure is None else pure[rows, cols],
        None if interior is None else interior[rows, cols],  # erosion of the crop: the same pixels (see _unmix)
    )
    if weights is not None:
        full[rows, cols] = weights
    return full


def _unmix(
    lin: F32,
    core: BoolArray,
    ring_px: int,
    exclude: BoolArray | None,
    pure: BoolArray | None,
    interior: BoolArray | None = None,
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
    if exclude is not None:
        region = region > (exclude > core)  # region & (~exclude | core)
        outer = outer > exclude
    if interior is None:
        interior = erode(core, 1)
    if not np.count_nonzero(interior):  # count_nonzero: a quarter of the cost of any() on a crop
        interior = core
    if np.count_nonzero(outer) < 4:
        return None
    sample = interior & pure if pure is not None else interior
    marker = _mean(lin, sample if np.count_nonzero(sample) else interior)
    lum = cv2.transform(lin, _CHANNEL_SUM)  # a tenth of the cost of numpy's sum over three channels
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
    affine = np.array([[r0, r1, r2, -(dark[0] * r0 + dark[1] * r1 + dark[2] * r2)]], np.float32)
    share = cv2.transform(lin, affine)
    np.minimum(np.maximum(share, -0.5, out=share), 1.0, out=share)  # clipped in place (np.clip's wrapper costs more)
    # the ring (region & ~interior) unmixed, the interior whole (1.0), the rest nothing
    out = interior.astype(np.float32)
    np.copyto(out, share, where=region > interior)  # cheaper than np.where, which would promote the booleans
    return out


def _mean(values: F32, mask: BoolArray) -> tuple[float, float, float]:
    """The mean of the masked pixels of an (h, w, 3) image, per channel."""
    b, g, r, _ = cv2.mean(values, mask=mask.view(np.uint8))  # zeros for an empty mask
    return b, g, r
