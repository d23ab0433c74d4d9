"""The background model (the paper's eq. 2): a reference frame of the empty scene, compared in normalised chroma.

The reference is compared in normalised chroma (lighting-invariant), and is refreshed a band of rows per frame,
never inside the regions of rovers being tracked, so a parked rover is not absorbed into the reference. It knows
which of its pixels show the empty scene (``valid``) and in which refresh each row was copied, so that what it
copied while a rover went unseen is not taken for the floor once the rover is found.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from edge.segmentation import F32, U8, BoolArray, dilate, opponent_planes

__all__ = ["BackgroundModel", "normalised_chroma", "subtract_background"]

FORGET_PX = 4  # the reference this far round a marker found anew may show it (BackgroundModel.forget)


def normalised_chroma(bgr: U8) -> tuple[F32, F32]:
    """Chroma divided by luminance: unchanged when the light level changes (drift, flicker, exposure)."""
    c1, c2, lum = opponent_planes(bgr)
    inv = np.float32(1.0) / np.maximum(lum, np.float32(8.0))
    return np.asarray(c1 * inv, np.float32), np.asarray(c2 * inv, np.float32)


def subtract_background(current: U8, reference: U8, threshold: float) -> BoolArray:
    """eq. 2 in a lighting-invariant space: ``|chroma(I_c) - chroma(I_r)| > Th`` per pixel, (H, W) bool.

    ``threshold`` is in units of normalised chroma (0.1 is a clearly different colour; a 35% change of the light
    level changes nothing).
    """
    a1, a2 = normalised_chroma(current)
    b1, b2 = normalised_chroma(reference)
    d1, d2 = a1 - b1, a2 - b2
    return np.asarray(d1 * d1 + d2 * d2 > np.float32(threshold * threshold))


class BackgroundModel:
    """The reference frame ``I_r`` of eq. 2, refreshed periodically without absorbing tracked rovers.

    The paper replaces the whole reference on a timer. Here a band of rows is refreshed every frame so that the
    whole reference is renewed once per ``period_frames`` at a constant, small cost, and pixels inside
    ``exclude`` boxes (the rovers being tracked, parked or not) are never copied. ``valid`` marks pixels whose
    reference is known to show the empty scene: all of them when an empty frame was given, else only those
    refreshed at least once while no tracked rover covered them.
    """

    def __init__(self, shape_hw: tuple[int, int], period_frames: int, empty_scene: U8 | None = None) -> None:
        h, w = shape_hw
        self.period_frames = max(1, int(period_frames))
        self.reference: U8 = np.zeros((h, w, 3), np.uint8)
        self.valid: BoolArray = np.zeros((h, w), bool)
        self._next_row = 0
        self._band = max(1, math.ceil(h / self.period_frames))
        self._frame = 0
        self.row_frames = np.full(h, -1, np.int64)  # the refresh each row was last copied in (-1: the empty scene)
        if empty_scene is not None:
            if empty_scene.shape[:2] != (h, w):
                raise ValueError(f"empty scene is {empty_scene.shape[1]}x{empty_scene.shape[0]}, frames are {w}x{h}")
            self.reference[...] = empty_scene
            self.valid[...] = True
        self._started = empty_scene is not None

    @property
    def shape_hw(self) -> tuple[int, int]:
        return self.reference.shape[0], self.reference.shape[1]

    def refresh(self, frame: U8, exclude: Sequence[tuple[int, int, int, int]]) -> slice:
        """Copy the next band of rows of ``frame`` into the reference, except inside ``exclude`` boxes; returns the
        rows it refreshed.

        ``exclude``: ``(x0, y0, x1, y1)`` pixel boxes (exclusive ends). The first call with no empty scene copies
        the whole frame (so the reference is never black) but marks nothing valid under the boxes.
        """
        h = self.reference.shape[0]
        if not self._started:
            rows = slice(0, h)
            self._started = True
        else:
            r0 = self._next_row
            rows = slice(r0, min(h, r0 + self._band))
            self._next_row = 0 if rows.stop >= h else rows.stop
        # The band is copied whole and the boxes' parts of it put back: a dozen times quicker than a masked copy.
        held = []
        for x0, y0, x1, y1 in exclude:
            ya, yb = max(y0, rows.start), min(y1, rows.stop)
            if ya < yb and x0 < x1:
                part = (slice(ya, yb), slice(max(0, x0), max(0, x1)))
                held.append((part, self.reference[part].copy(), self.valid[part].copy()))
        first = rows.start == 0 and rows.stop == h and not self.valid.any()
        # first frame: a reference to compare with everywhere, valid only outside the boxes
        self.reference[rows] = frame[rows]
        self.valid[rows] = True
        self.row_frames[rows] = self._frame
        self._frame += 1
        for part, reference, valid in held:
            if not first:
                self.reference[part] = reference
            self.valid[part] = valid
        return rows

    def valid_since(self, box: tuple[int, int, int, int], since: int) -> BoolArray:
        """``valid`` inside ``box`` less the rows copied in refresh ``since`` or later: what the reference there
        shows of the time before something appeared in it (a rover found now may have stood there since)."""
        x0, y0, x1, y1 = box
        return np.asarray(self.valid[y0:y1, x0:x1] & (self.row_frames[y0:y1] < since)[:, None])

    def forget(self, box: tuple[int, int, int, int], since: int, marker: F32 | None) -> None:
        """Mark invalid what :meth:`valid_since` leaves out of ``box`` round a rover's marker found there, unseen
        since refresh ``since``: ``marker``, its coverage (the box's shape; None: the whole box), and
        :data:`FORGET_PX` round it (its blur, its edge's ring). The band's refresh leaves a tracked rover's box
        alone, so without this what was copied of it while it was unseen would stay "the floor" under it."""
        x0, y0, x1, y1 = box
        keep = self.valid_since(box, since)
        if marker is not None:
            keep |= ~dilate(marker > 0.0, FORGET_PX)
        self.valid[y0:y1, x0:x1] &= keep

    def foreground(self, frame_roi: U8, roi: tuple[int, int, int, int], threshold: float) -> BoolArray:
        """eq. 2 inside ``roi`` = ``(x0, y0, x1, y1)``: True where the frame differs from a *valid* reference."""
        x0, y0, x1, y1 = roi
        diff = subtract_background(frame_roi, self.reference[y0:y1, x0:x1], threshold)
        return np.asarray(diff & self.valid[y0:y1, x0:x1])
