"""Is a blob that shows less than a whole marker's area still the whole marker? Its shape says.

A compressed stream moves a marker's boundary: 4:2:0 chroma at a low JPEG quality can take a tenth or more of a
far-side marker's area for a while, all round its outline. A leg, a box's edge or a foot takes a part of one side.
The two differ in symmetry: a rectangle worn down all round stays symmetric about its centre and grows a little
more elongated; one with a part hidden is lopsided (its centre moves toward the part left), or, cut straight across
an end or a side, symmetric but of the wrong elongation. Not every hidden part shows: strips hidden along an end and
a side at once leave a smaller rectangle of a worn marker's shape whose centre is off by the strips' width, which
only the rover's motion can tell (``edge.rover_track.symmetric_below`` checks the filter's prediction too).

:func:`point_asymmetry` measures the lopsidedness (third moments in whitened coordinates: unchanged by the
marker's size in pixels and by any affine view of it; the perspective's few percent across a marker are not
removed and alone give 0.06-0.08); :func:`eroded_elongation` gives the elongation a rectangle worn down all round
keeps. A stream wears it evenly in pixels, not on the floor: where the view is foreshortened (the far side's pixel
spans 2-3 times as much floor along the image's columns as along its rows) the sides that run along the rows lose
more floor than the others, and a worn marker lined up with the rows is 6-9 % more elongated than one worn evenly
on the floor (:func:`wear_stretch` gives the ratio for a marker's axis and the view there).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.segmentation import F32

FloatArray = NDArray[np.float64]
IN_VIEW_MARGIN_PX = 0.0  # a blob at the image border is a whole marker when its modelled corners lie this far inside
OPEN_SHARE = 0.22  # marker_part's opening radius, as a share of the square root of the marker's area (in pixels)
PART_AREA = (0.75, 1.15)  # ... and the area of the part it keeps, as a share of the marker's expected area
PARTED = 0.08  # ... when it parts off one piece this large at least (same share)


def point_asymmetry(weights: F32) -> float:
    """How lopsided the weighted blob ``weights`` ((h, w) coverage) is: the norm of its third central moments in
    coordinates whitened by its covariance (0 for any shape symmetric about its centre; 0.34 for a 21.5 x 16.8 cm
    marker with a 5.5 x 4.5 cm corner hidden, 7 % of it, 0.48 with 12 %). ``inf`` for a blob with no extent, or
    weights that are not finite."""
    h, w = weights.shape
    # a shape has no negative mass: the coverage's negative shares (a sharpened edge's dark halo, noise beyond the
    # edge, kept there so that they average out of the centre) count as nothing
    m = np.maximum(weights, 0.0, dtype=np.float64)
    # every moment up to the third from one product: raw[b, a] = sum of m * x**a * y**b (about the window's middle)
    x = np.arange(w, dtype=np.float64) - 0.5 * (w - 1)
    y = np.arange(h, dtype=np.float64) - 0.5 * (h - 1)
    raw = np.vander(y, 4, increasing=True).T @ m @ np.vander(x, 4, increasing=True)
    s = float(raw[0, 0])
    if not (s > 1e-9 and math.isfinite(s)):  # nothing there, or NaN weights
        return math.inf
    r = raw / s
    cx, cy = float(r[0, 1]), float(r[1, 0])
    xx = float(r[0, 2]) - cx * cx
    xy = float(r[1, 1]) - cx * cy
    yy = float(r[2, 0]) - cy * cy
    det = xx * yy - xy * xy
    if det <= 1e-12 or xx <= 0.0:
        return math.inf
    # the central third moments E[dx**p dy**q], p + q = 3
    m30 = float(r[0, 3]) - 3.0 * cx * float(r[0, 2]) + 2.0 * cx**3
    m03 = float(r[3, 0]) - 3.0 * cy * float(r[2, 0]) + 2.0 * cy**3
    m21 = float(r[1, 2]) - 2.0 * cx * float(r[1, 1]) - cy * float(r[0, 2]) + 2.0 * cx * cx * cy
    m12 = float(r[2, 1]) - 2.0 * cy * float(r[1, 1]) - cx * float(r[2, 0]) + 2.0 * cx * cy * cy
    # whitened by the Cholesky factor of the inverse covariance: a = dx / s1, b = (xx dy - xy dx) / s2
    s1, s2 = math.sqrt(xx), math.sqrt(xx * det)
    t = [
        m30 / s1**3,
        (xx * m21 - xy * m30) / (s1 * s1 * s2),
        (xx * xx * m12 - 2.0 * xx * xy * m21 + xy * xy * m30) / (s1 * s2 * s2),
        (xx**3 * m03 - 3.0 * xx * xx * xy * m12 + 3.0 * xx * xy * xy * m21 - xy**3 * m30) / s2**3,
    ]
    # the norm of the symmetric third-moment tensor (each mixed term counted as often as it appears)
    return math.sqrt(t[0] ** 2 + 3.0 * t[1] ** 2 + 3.0 * t[2] ** 2 + t[3] ** 2)


def marker_part(
    core: NDArray[np.bool_], expected_px: float, at_px: tuple[float, float]
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]] | None:
    """The marker's part of a blob ``core`` that joined it to something of its hue (a shadow tinted by the sky's
    light, another object's coloured part touching it): the blob opened by a disk of radius ``OPEN_SHARE`` of the
    marker's expected size (``expected_px``; a quarter of a 21.5 x 16.8 cm marker's width), which cuts what joins
    them and keeps a rectangle but for its corners' rounding, then the part nearest ``at_px`` (window pixels) if its
    area is a marker's (``PART_AREA``). Returned with what it left of the blob beyond the corners' reach (for the
    edge weights to leave out); None when the opening parts no piece of ``PARTED`` of the marker's area off (a
    small marker's ragged edge loses several per cent in bits) or leaves no marker-sized part."""
    radius = max(1, round(OPEN_SHARE * math.sqrt(max(expected_px, 1.0))))
    x, y, w, h = cv2.boundingRect(core.view(np.uint8))  # the blob alone, with room for the disk: a few times quicker
    x0, y0 = max(x - radius, 0), max(y - radius, 0)
    box = (slice(y0, y + h + radius), slice(x0, x + w + radius))
    blob = core[box]
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    opened = cv2.morphologyEx(blob.view(np.uint8), cv2.MORPH_OPEN, disk, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    count, labels, stats, centres = cv2.connectedComponentsWithStats(opened, connectivity=8)
    lo, hi = PART_AREA
    fits = [i for i in range(1, count) if lo * expected_px <= stats[i, cv2.CC_STAT_AREA] <= hi * expected_px]
    if not fits:
        return None
    u, v = at_px[0] - x0, at_px[1] - y0
    best = min(fits, key=lambda i: math.hypot(centres[i][0] - u, centres[i][1] - v))
    part = labels == best
    reach = math.ceil((math.sqrt(2.0) - 1.0) * radius)  # a rounded corner lies this far inside the square one
    ring = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
    rest = blob & ~(cv2.dilate(part.view(np.uint8), ring) > 0)
    count, _, stats, _ = cv2.connectedComponentsWithStats(rest.view(np.uint8), connectivity=8)
    if count < 2 or stats[1:, cv2.CC_STAT_AREA].max() < PARTED * expected_px:
        return None  # no piece parted off, only a ragged edge's bits: the blob is the marker
    whole_part, whole_rest = np.zeros_like(core), np.zeros_like(core)
    whole_part[box], whole_rest[box] = part, rest
    return whole_part, whole_rest


def eroded_elongation(area_ratio: float, aspect: float, stretch: float = 1.0) -> float:
    """The elongation (long over short side) of an ``aspect`` rectangle worn down all round to ``area_ratio`` of its
    area, as a share of ``aspect`` (1 for no wear; 1.03 for a 21.5 x 16.8 cm marker at 0.8), its long sides worn by
    ``stretch`` times the floor its ends lose (1: the same width all round; :func:`wear_stretch` for a stream's
    wear in pixels)."""
    length, width = math.sqrt(aspect), 1.0 / math.sqrt(aspect)  # area 1
    r, k = min(max(area_ratio, 0.0), 1.0), stretch
    # (length - u)(width - k u) = r: the smaller root is the length worn off both ends together
    u = ((k * length + width) - math.sqrt((k * length + width) ** 2 - 4.0 * k * (1.0 - r))) / (2.0 * k)
    return ((length - u) / (width - k * u)) / aspect if width - k * u > 1e-9 else math.inf


def wear_stretch(cm_per_px: FloatArray, axis_rad: float) -> float:
    """How many times as much floor a marker's long sides lose as its ends, when the stream wears its outline by the
    same pixels all round: ``cm_per_px`` the plane's (2, 2) Jacobian d(x, y)/d(u, v) at the marker, ``axis_rad`` its
    long axis on the plane.

    Moving a side ``d`` cm along its normal moves its image ``d |det A| / |A t|`` pixels across it (``A``: the
    plane-to-image map, ``t``: the side's direction), so ``delta`` pixels are ``delta |A t| / |det A|`` cm: the long
    sides (along the axis ``a``) over the ends (along ``b``, across it) give ``|A a| / |A b|``; 1 where the view
    is not foreshortened or nothing is known (a Jacobian with no inverse)."""
    try:
        to_image = np.linalg.inv(np.asarray(cm_per_px, dtype=np.float64))
    except np.linalg.LinAlgError:
        return 1.0
    c, s = math.cos(axis_rad), math.sin(axis_rad)
    along = float(np.hypot(*(to_image @ np.array([c, s]))))
    across = float(np.hypot(*(to_image @ np.array([-s, c]))))
    stretch = along / across if across > 0.0 else math.nan
    return stretch if math.isfinite(stretch) and stretch > 0.0 else 1.0


def footprint_in_view(
    to_pixel: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]],
    centre_cm: tuple[float, float],
    axis_rad: float,
    size_cm: tuple[float, float],
    image_size: tuple[int, int],
    margin_px: float,
) -> bool:
    """Does a marker of ``size_cm`` (length along ``axis_rad``, width) centred at ``centre_cm`` lie wholly in the
    image (``image_size``: width, height), every corner at least ``margin_px`` inside its border? ``to_pixel`` maps
    plane points to pixels (pixel centres at whole numbers: the image spans -0.5 .. size - 0.5).

    A blob that touches the image border is either a marker the border cuts off or a whole one whose blurred edge
    reaches it. Placed at a cut marker's centre, which moves inward by half the part cut off, the modelled marker
    still crosses the border (by the other half); a whole marker's lies inside. NaN (no pixel): not in view."""
    c, s = math.cos(axis_rad), math.sin(axis_rad)
    hl, hw = 0.5 * size_cm[0], 0.5 * size_cm[1]
    along = np.array([hl, hl, -hl, -hl])
    across = np.array([hw, -hw, -hw, hw])
    u, v = to_pixel(centre_cm[0] + along * c - across * s, centre_cm[1] + along * s + across * c)
    w, h = image_size
    lo = margin_px - 0.5
    inside = (u >= lo) & (u <= w - 0.5 - margin_px) & (v >= lo) & (v <= h - 0.5 - margin_px)
    return bool(np.all(inside))  # NaN compares False
