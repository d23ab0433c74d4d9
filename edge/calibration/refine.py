"""Clicked survey points moved onto the printed targets under them, to a fraction of a pixel.

A person clicking a survey point in a photo is good to about half a pixel. That is the floor of a point-pair
calibration: its error is a fixed field over the floor, so every rover that drives through a place carries the same
error there, and over a run it is a bias, not a scatter. With 34 points clicked to 0.5 px (RMS, radial), a tracker
without any error of its own would show a per-rover bias over 0.05 cm on most runs of the camera family; clicked to
0.1 px, on few (``benchmarks/bench_calibration_floor.py``, ``docs/calibration.md``).

So each survey point may carry a printed *target*: a 2 x 2 checker (two dark and two light squares meeting at the
point), whose centre is an X-corner, a saddle of the image's brightness that stays a saddle under any perspective.
:func:`refine_clicks` fits a quadratic to the smoothed image round each click and moves it to the quadratic's saddle,
again until it stays (:func:`saddle_point`): first on a coarser smoothing (a sharp corner's saddle is a pixel wide and
a click may be further off), then on a finer one from there and from the eight pixels round it (:func:`_corner`: a
far target's squares are 3 px tall, and one start may slide to the card's edge). It keeps the result only where it
really is an X-corner: round it, the brightness alternates dark, light, dark, light (its second circular harmonic
carries at least :data:`MIN_SADDLE` of the contrast), the contrast is at least :data:`MIN_CONTRAST_DN`, and the
corner is within :data:`MAX_MOVE_PX` of the click. Elsewhere the click stands as it was (the caller names it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.files import CalibrationFile

FloatArray = NDArray[np.float64]

SMOOTH_PX = 1.0  # the image is smoothed by a Gaussian of this sigma before the saddle is fitted
HALF_FIT_PX = 1  # the quadratic is fitted to the 3 x 3 px round the nearest pixel (5 x 5 takes in a far card's edge)
ITERATIONS = 12
SETTLED_PX = 0.5  # a last step this short is a fit swinging between two windows, not one still moving
COARSE_SMOOTH_PX, COARSE_HALF_PX = 2.0, 2  # the first, rough saddle (a click over a pixel off a sharp corner)
MAX_MOVE_PX = 3.0  # a corner further from the click is some other corner (or none)
MIN_CONTRAST_DN = 20.0  # the target's dark and light squares differ by this much at least (8-bit)
MIN_SADDLE = 0.35  # the ring's second harmonic over its half range: the targets' corners 0.9-1, an edge or a dot ~0
RING_RADII_PX = (1.5, 2.5)  # where the alternation is read round the corner (inside a far target's 3 px squares)
RING_SAMPLES = 32
AGREE_PX = 0.25  # the starts' saddles within this of their median are one corner
CLICKED_SIGMA_PX = 0.15  # a point-pair fit's residual this large or more: clicked by hand (0.3-0.4 px); targets 0.03


@dataclass(frozen=True)
class Refined:
    """``uv_px`` (N, 2): each click on its target's corner where one was found, as clicked elsewhere; ``found``
    (N,): which were; ``moved_px`` (N,): how far each was moved (0 where not found)."""

    uv_px: FloatArray
    found: NDArray[np.bool_]
    moved_px: FloatArray


def grey(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """A BGR or grey 8-bit image as grey."""
    return image if image.ndim == 2 else np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), np.uint8)


def saddle_strength(gray: NDArray[np.uint8], uv_px: tuple[float, float]) -> tuple[float, float]:
    """Round ``uv_px``: the brightness's range (8-bit) and its second circular harmonic's amplitude over half that
    range (about 1 for an X-corner, whose ring is two periods of a blurred square wave; a straight edge or a dot has
    almost none)."""
    angles = np.linspace(0.0, 2.0 * np.pi, RING_SAMPLES, endpoint=False)
    rings = []
    for r in RING_RADII_PX:
        map_x = (uv_px[0] + r * np.cos(angles)).astype(np.float32).reshape(1, -1)
        map_y = (uv_px[1] + r * np.sin(angles)).astype(np.float32).reshape(1, -1)
        rings.append(cv2.remap(gray, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0])
    ring = np.mean(np.asarray(rings, np.float64), axis=0)
    spread = float(ring.max() - ring.min())
    if spread <= 0.0:
        return 0.0, 0.0
    second = 2.0 * abs(complex(np.dot(ring, np.exp(-2j * angles)))) / RING_SAMPLES
    return spread, second / (0.5 * spread)


@lru_cache(maxsize=4)
def _quadratic_fit(half: int) -> FloatArray:
    """(6, n) least squares of ``a x^2 + b x y + c y^2 + d x + e y + f`` over a (2 ``half`` + 1) px square's
    pixels (row-major); read-only (cached)."""
    dy, dx = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float64)
    design = np.column_stack([dx.ravel() ** 2, (dx * dy).ravel(), dy.ravel() ** 2, dx.ravel(), dy.ravel()])
    solve = np.linalg.pinv(np.column_stack([design, np.ones(dx.size)]))
    solve.flags.writeable = False
    return solve


def saddle_point(
    smooth: NDArray[np.float32], uv_px: tuple[float, float], half: int = HALF_FIT_PX
) -> tuple[float, float] | None:
    """The saddle of the smoothed image nearest ``uv_px``: a quadratic ``a x^2 + b x y + c y^2 + d x + e y + f``
    fitted to the (2 ``half`` + 1) px square round the nearest pixel, moved to where its gradient vanishes, again
    until it stays (None: no saddle there, the image's border, or still moving after :data:`ITERATIONS`). Near a
    pixel's border the window changes with the estimate, and the two windows' saddles may take turns a few
    hundredths apart: then the middle of the last two."""
    h, w = smooth.shape
    solve = _quadratic_fit(half)
    x, y = px, py = uv_px
    step = math.inf
    for _ in range(ITERATIONS):
        cx, cy = round(x), round(y)
        if not (half <= cx < w - half and half <= cy < h - half):
            return None
        patch = smooth[cy - half : cy + half + 1, cx - half : cx + half + 1]
        a, b, c, d, e, _ = solve @ patch.astype(np.float64).ravel()
        det = 4.0 * a * c - b * b
        if det >= 0.0:  # a peak, a pit or a ridge: not an X-corner
            return None
        nx, ny = cx + (b * e - 2.0 * c * d) / det, cy + (b * d - 2.0 * a * e) / det
        step = math.hypot(nx - x, ny - y)
        (px, py), (x, y) = (x, y), (nx, ny)
        if step < 0.005:
            return x, y
    return ((x + px) / 2.0, (y + py) / 2.0) if step < SETTLED_PX else None


def _corner(smooth: NDArray[np.float32], u: float, v: float) -> tuple[float, float] | None:
    """The saddle near the click ``u, v``, started from the click and the eight pixels round it: on a far target
    (its squares 3 px tall) a fit from one pixel may find no saddle or slide to the card's edge; the median of those
    that agree with it (within :data:`AGREE_PX`), with at least three agreeing (None otherwise)."""
    found = [p for du in (-1, 0, 1) for dv in (-1, 0, 1) if (p := saddle_point(smooth, (u + du, v + dv))) is not None]
    if len(found) < 3:
        return None
    pts = np.asarray(found)
    centre = np.median(pts, axis=0)
    agree = pts[np.hypot(*(pts - centre).T) <= AGREE_PX]
    if len(agree) < 3:
        return None
    x, y = np.median(agree, axis=0)
    return float(x), float(y)


def refine_clicks(image: NDArray[np.uint8], uv_px: FloatArray) -> Refined:
    """Each click of ``uv_px`` (N, 2; pixel centres at integers) moved to the X-corner of the target under it in
    ``image`` (BGR or grey), where there is one (the module docstring)."""
    gray = grey(image)
    smooth = np.asarray(cv2.GaussianBlur(gray.astype(np.float32), (0, 0), SMOOTH_PX), np.float32)
    coarse = np.asarray(cv2.GaussianBlur(gray.astype(np.float32), (0, 0), COARSE_SMOOTH_PX), np.float32)
    clicks = np.asarray(uv_px, np.float64).reshape(-1, 2)
    out = clicks.copy()
    found = np.zeros(len(clicks), bool)
    for i, (u, v) in enumerate(clicks.tolist()):
        near = saddle_point(coarse, (u, v), COARSE_HALF_PX)  # a sharp corner's saddle is a pixel wide: come near first
        if near is not None and math.hypot(near[0] - u, near[1] - v) <= MAX_MOVE_PX:
            corner = _corner(smooth, *near)
        else:
            corner = _corner(smooth, u, v)
        if corner is None or math.hypot(corner[0] - u, corner[1] - v) > MAX_MOVE_PX:
            continue
        spread, saddle = saddle_strength(gray, corner)
        if spread >= MIN_CONTRAST_DN and saddle >= MIN_SADDLE:
            out[i], found[i] = corner, True
    moved = np.where(found, np.hypot(*(out - clicks).T), 0.0)
    return Refined(out, found, moved)


def clicked_by_hand(record: CalibrationFile) -> float | None:
    """A point-pair calibration's fit residual (px) where it says its points were clicked by hand (at least
    :data:`CLICKED_SIGMA_PX`: refined on printed targets they fit to a few hundredths); None otherwise."""
    sigma = record.fit.sigma_px if record.method == "points" and record.fit is not None else None
    return sigma if sigma is not None and sigma >= CLICKED_SIGMA_PX else None


def clicked_note(sigma_px: float) -> str:
    """What a calibration from points clicked by hand means for the positions (doctor, the dashboard)."""
    return (
        f"its points fit with {sigma_px:.2f} px residuals, clicked by hand: over a run each rover carries the "
        "mapping's error there as a bias (about 0.1 cm)"
    )
