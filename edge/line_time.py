"""A camera's rolling-shutter line time, read off the mains flicker its rows show (``edge-ips calibrate line-time``).

Lamps on mains power ripple at twice the mains frequency. A rolling shutter exposes row ``r`` ``r * line_time``
after row 0, so the ripple shows as horizontal bands ``1 / (2 * mains_hz * line_time)`` rows apart, which roll
from frame to frame (unless the frame rate divides twice the mains frequency: 30 fps under 60 Hz, 25 fps under
50 Hz). A short exposure makes them strong (an exposure of whole ripple periods cancels them). Each frame's mean
row brightness over the median of the frames' (the scene, which the rolling bands leave) is the bands alone; the
period, among those a rolling shutter can give (read out within one frame period: at least ``fps * rows /
(2 * mains_hz)`` rows apart; at most 0.9 of a frame's height: longer ones are refused, as a fit to less than a
band lands on the searched range's end), whose sinusoid explains most of them (least
squares, each frame its own phase) is theirs: a frame holds only 1-3 periods, too few for a spectrum's peak. The
tracker's ``line_time_us`` (``docs/tracking.md``, "A rolling shutter") is what this prints.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.errors import SourceError

MIN_FRAMES = 8  # the median over the frames must leave the scene without the bands
MIN_SHARE = 0.3  # the bands must explain this share of the rows' variation (beyond a slope) ...
MIN_CONTRAST = 0.002  # ... and be this strong (amplitude, a share of the brightness)
STEP = 0.004  # the periods tried are this far apart (relative), then refined between the best one's neighbours
LONGEST = 1.5  # the longest band period tried, in frame heights ...
EDGE = 0.6  # ... of which a period found beyond this share is refused: too few bands a frame to fit (0.9 frames)


class NoFlicker(SourceError):
    """The frames show no rolling flicker bands to measure a line time by."""


@dataclass(frozen=True)
class LineTime:
    """``line_time_us``: the time between two rows' exposures; ``period_rows``: the bands' period;
    ``contrast``: their amplitude, a share of the brightness; ``share``: the share of the rows' variation (beyond a
    slope) they explain; ``frames``: how many frames were measured."""

    line_time_us: float
    period_rows: float
    contrast: float
    share: float
    frames: int


def line_time_from_flicker(frames: Sequence[NDArray[np.uint8]], mains_hz: float, fps: float) -> LineTime:
    """The line time of the camera that took ``frames`` (BGR, at ``fps``) under lamps on ``mains_hz`` mains.

    Raises :class:`NoFlicker` when the frames are too few or show no bands (with what to change)."""
    if mains_hz <= 0 or fps <= 0:
        raise ValueError("mains_hz and fps must be positive")
    if len(frames) < MIN_FRAMES:
        raise NoFlicker(f"{len(frames)} frames: at least {MIN_FRAMES} are needed")
    ripple = 2.0 * mains_hz
    if abs(ripple / fps - round(ripple / fps)) < 0.02:
        raise NoFlicker(
            f"at {fps:g} fps the bands of {mains_hz:g} Hz mains stand still from frame to frame and cannot be told "
            f"from the scene: measure at another frame rate ({'25' if mains_hz == 60 else '30'} fps)"
        )
    rows = np.stack([_row_means(f) for f in frames])  # (n, H)
    rows /= np.maximum(rows.mean(axis=1, keepdims=True), 1e-6)  # exposure changes between frames left out
    bands = (rows / np.maximum(np.median(rows, axis=0), 1e-6) - 1.0).T  # (H, n)
    height = bands.shape[0]
    shortest = 0.95 * fps * height / ripple  # read out within a frame period
    longest = LONGEST * height
    if shortest >= longest:
        raise NoFlicker(f"{height} rows are too few to show bands {shortest:.0f} rows apart or more")
    trend = _basis(height, None)
    residual = bands - trend @ np.linalg.lstsq(trend, bands, rcond=None)[0]  # what a slope leaves
    periods = np.geomspace(shortest, longest, int(math.log(longest / shortest) / STEP) + 2)
    explained = np.array([_explained(residual, p) for p in periods])
    best = int(np.argmax(explained))
    fine = np.geomspace(periods[max(best - 1, 0)], periods[min(best + 1, len(periods) - 1)], 41)
    explained_fine = np.array([_explained(residual, p) for p in fine])
    period = float(fine[int(np.argmax(explained_fine))])
    share = float(explained_fine.max() / max(float((residual**2).sum()), 1e-30))
    amplitude = float(np.sqrt(2.0 * explained_fine.max() / bands.size))
    if period > EDGE * longest:
        raise NoFlicker(
            f"the bands are {period:.0f} rows apart or more, too far for {height} rows to measure: the camera "
            f"reads out fast (under {1e6 / (ripple * EDGE * longest):.0f} us a row); measure at a larger image "
            "size, or leave line_time_us at 0 (its skew is then small)"
        )
    if share < MIN_SHARE or amplitude < MIN_CONTRAST:
        raise NoFlicker(
            "no flicker bands in the frames: look at the floor under mains-powered lamps (not daylight, not DC LED "
            "drivers) with a short manual exposure (exposure = 5, 0.5 ms) for the measurement"
            f" (bands explain {100 * share:.0f} % of the rows' variation, contrast {100 * amplitude:.2f} %)"
        )
    return LineTime(1e6 / (ripple * period), period, amplitude, share, len(frames))


def _basis(height: int, period: float | None) -> NDArray[np.float64]:
    """(H, 2) a constant and a slope along the rows (what the median leaves of the light's changes), and with
    ``period`` (H, 4) the bands' cosine and sine too."""
    r = np.arange(height, dtype=np.float64)
    columns = [np.ones(height), r / height - 0.5]
    if period is not None:
        columns += [np.cos(2.0 * math.pi * r / period), np.sin(2.0 * math.pi * r / period)]
    return np.stack(columns, axis=1)


def _explained(residual: NDArray[np.float64], period: float) -> float:
    """How much of ``residual`` (H, n: the rows' variation less a constant and a slope) bands of ``period`` rows
    explain (least squares, every frame its own phase)."""
    with_bands = _basis(residual.shape[0], period)
    fit = with_bands @ np.linalg.lstsq(with_bands, residual, rcond=None)[0]
    return float((fit**2).sum())


def _row_means(image: NDArray[np.uint8]) -> NDArray[np.float64]:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return np.asarray(grey, np.float64).mean(axis=1)
