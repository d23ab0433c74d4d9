"""Colour relative to the local light: each window seen as if lit by the room's usual white.

A marker's colour in the image is its paper's colour times the light where it stands. Under a warm sunlit patch a
blue marker turns grey-violet, under a cold skylight a red one turns pink, and an automatic white balance moves every
colour as the scene changes; judged against the colours configured under the lamps, such a marker can fall out of
its hue's tolerance and be lost. The floor around it is lit by the same light, and the background model knows the
floor: its reference is a local white reference at every pixel.

:class:`LocalWhite` keeps

* ``white``: the floor's mean colour (linear light) over the whole view when tracking started: the light the marker
  colours were configured under;
* a coarse map of the reference's colour (blocks of 32 pixels, a tile or more of floor: the floor's own pattern,
  grout and tape average out, the light's slow variation across the room, a sunlit patch, stays), refreshed as the
  reference is; a block whose colour no light has (a poster of a marker's hue on the floor) counts as the white;
* ``light``: that map with each block's colour the median of its own and its 8 neighbours' (per channel). A wooden
  floor's planks differ in tint from one block to the next by as much as a sunlit patch differs from the lamps (0.02
  to 0.05 in chromaticity), and block by block each plank's tint was corrected as if it were the light. The median
  about halves a block's own tint and keeps the light of a patch three blocks wide or more (docs/benchmarks.md,
  "The light's map smoothed over its blocks").

For a window, the light there now is the light map's colour there, corrected by how the floor just around the
window has changed since the reference was taken (median ratio of the window's border pixels to the reference's:
the automatic white balance and passing clouds act between refreshes). Only border pixels whose brightness changed
about as the whole view's did (:meth:`LocalWhite.observe`, within :data:`FLOOR_BAND` of it) count as floor: a
rover's own black body can fill most of its window's border, and over wood its ratio to the floor (a twelfth of its
brightness, relatively bluer) read as a blue light that moved a teal marker out of its hue for a second. Where too
few are left, the light there is the map's changed as the whole view has. The window's pixels are then divided by that
light's colour and multiplied by ``white`` (a von Kries correction, per channel in linear light, brightness kept):
the marker shows the colour it had under the lamps, and a grey or white object stays grey.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.segmentation import LINEAR, U8, BoolArray, linear_bgr

FloatArray = NDArray[np.float64]
BLOCK_PX = 32
MAX_GAIN = 2.5  # no channel is corrected more than this (a saturated or black floor says little about the light)
# Lamps, daylight and sunlight (2700 K to 6500 K) differ in chromaticity by under 0.15 in any channel: a block of the
# reference farther than this from the configured white is a coloured thing lying on the floor (a poster, a rug, a
# parked object of a marker's hue), not the light's colour.
MAX_LIGHT_SHIFT = 0.2
# A floor pixel on a window's border changes its brightness about as the whole view does (the white balance, the
# exposure, the lamps' drift act on all of it; a cloud on a sunlit patch or a lamp switched off nearby by a factor
# of 2-3 more); a black body there is 5-30 times darker than the floor it covers.
FLOOR_BAND = (0.3, 3.3)
VIEW_SAMPLES = 1024  # pixels of the view sampled for its change (a sparse grid)
MIN_VIEW_SAMPLES = 64
OBSERVE_EVERY = 4  # frames between two measures of the view's change (edge.pipeline: the light changes over seconds)
_ENCODE = np.asarray(np.interp(np.linspace(0.0, 1.0, 4096), LINEAR, np.arange(256)).round(), dtype=np.uint8)
_ONES = np.ones(3, np.float32)
_LINEAR_COLUMN = LINEAR[:, None].copy()  # (256, 1): the look-up table of one gain per channel


def encode_linear(linear: NDArray[np.float32]) -> U8:
    """Linear light (0..1) back to 8-bit values through the sRGB tone curve (inverse of ``LINEAR``)."""
    # minimum/maximum and int32 indices read with take(): the same table entries as np.clip and fancy indexing, at a
    # fraction of their wrappers' cost on the small tables and windows this is called with
    index = np.minimum(np.maximum(linear * 4095.0 + 0.5, 0.0), 4095.0).astype(np.int32)
    return np.asarray(_ENCODE.take(index), dtype=np.uint8)


class LocalWhite:
    """The light's colour across the view, from the background reference (see the module's docstring)."""

    def __init__(self, reference: U8, valid: BoolArray) -> None:
        """``reference``: the background reference (its valid pixels: the empty floor); the configured white is
        the whole view's mean colour (a few rovers in it change it little)."""
        self.white = _chromaticity(_mean_colour(reference, np.ones(valid.shape, bool)))
        self.coarse = np.zeros((0, 0, 3))
        self.light = self.coarse
        self._edges: list[int] = []
        self.change = [1.0, 1.0, 1.0]  # the view's per-channel change since its reference was taken (observe)
        self.level = 1.0  # and its brightness's
        self.update(reference, valid)

    def observe(self, image: U8, reference: U8, valid: BoolArray) -> None:
        """The whole view's change of light since its reference was taken, from a sparse grid of its valid pixels:
        per channel and in brightness, the medians of their ratios to the reference (the white balance, the exposure
        and the lamps act on all of it; the rovers, a few per cent of the view, do not move the medians). Called
        every few frames (``edge.pipeline``: the light changes over seconds), before the windows' :meth:`gains`; too
        few valid pixels (the reference not yet known) leave no change."""
        index = _grid_index(*valid.shape[:2])
        usable = index.compress(valid.reshape(-1).take(index))
        if len(usable) < MIN_VIEW_SAMPLES:
            self.change, self.level = [1.0, 1.0, 1.0], 1.0
            return
        now = cv2.LUT(image.reshape(-1, 3).take(usable, axis=0), LINEAR) + np.float32(1e-4)
        then = cv2.LUT(reference.reshape(-1, 3).take(usable, axis=0), LINEAR) + np.float32(1e-4)
        self.change = [float(v) for v in _column_medians(now / then)]
        self.level = float(_column_medians(_brightness_ratio(now, then)[:, None].astype(np.float64))[0])

    def update(self, reference: U8, valid: BoolArray, rows: slice | None = None) -> None:
        """Recompute the coarse map from the current reference (where it is valid; elsewhere the global white): all
        of it, or only the rows of blocks whose last image row ``rows`` just refreshed (the background reference
        renews a band of rows per frame: a block row is recomputed once, when the band has passed all of it)."""
        h, w = reference.shape[:2]
        nh, nw = max(1, h // BLOCK_PX), max(1, w // BLOCK_PX)
        if rows is None or self.coarse.shape[:2] != (nh, nw):
            self.coarse = np.empty((nh, nw, 3))
            self._edges = [int(e) for e in np.linspace(0, h, nh + 1).round()]  # block rows' first image rows
            blocks = list(range(nh))
        else:
            blocks = [i for i in range(nh) if rows.start < self._edges[i + 1] <= rows.stop]
        edges = self._edges
        for i in blocks:
            self.coarse[i] = self._block_row(reference[edges[i] : edges[i + 1]], valid[edges[i] : edges[i + 1]], nw)
        if blocks:
            self.light = np.asarray(cv2.medianBlur(self.coarse.astype(np.float32), 3), np.float64)

    def _block_row(self, strip: U8, valid: BoolArray, blocks: int) -> FloatArray:
        """(blocks, 3) the light's chromaticity in each block of a strip of the reference."""
        # averaged in 8-bit values, then linearised: a block's colour is what matters, and this is 20 times cheaper
        lin = linear_bgr(np.asarray(cv2.resize(strip, (blocks, 1), interpolation=cv2.INTER_AREA), np.uint8))[0]
        share = cv2.resize(valid.astype(np.float32), (blocks, 1), interpolation=cv2.INTER_AREA).reshape(blocks)
        chroma = (lin / np.maximum(lin.sum(axis=1, keepdims=True), 1e-6)).astype(np.float64)
        chroma[share < 0.95] = self.white  # a block with a rover (or its unrefreshed ghost) in it says nothing
        chroma[np.abs(chroma - self.white).max(axis=1) > MAX_LIGHT_SHIFT] = self.white  # nor a coloured object
        return chroma

    def gains(
        self,
        box: tuple[int, int, int, int],
        crop: U8,
        reference: U8 | None,
        valid: BoolArray | None,
        others: Sequence[tuple[int, int, int, int]] = (),
    ) -> FloatArray:
        """(3,) per-channel gains that show the window ``box`` (``crop``, and the reference's crop with its
        validity) under the configured white. ``others``: the image boxes of the other rovers being tracked: their
        markers and bodies on the window's border are not floor, and say nothing of the light (three rovers in a
        row each took up more than half of the next one's border: the median then read a black body and a blue
        marker as the light, and a red marker, shown under a 1.65x red gain, grew by a third)."""
        x0, y0, x1, y1 = box
        cy = min(self.coarse.shape[0] - 1, ((y0 + y1) // 2) // BLOCK_PX)
        cx = min(self.coarse.shape[1] - 1, ((x0 + x1) // 2) // BLOCK_PX)
        coarse = self.light[cy, cx].tolist()  # three numbers: plain floats are quicker than arrays
        light = viewed = [a * b for a, b in zip(coarse, self.change, strict=True)]  # the map's, changed as the view
        if reference is not None and valid is not None:
            border = _border_index(*valid.shape[:2])
            floor = valid.reshape(-1).take(border)
            if others:
                floor = floor & ~_inside(border, valid.shape[1], box, others)
            usable = border.compress(floor)
            if len(usable) >= 8:
                # take() along the pixels: a third of the time of indexing them
                now = cv2.LUT(crop.reshape(-1, 3).take(usable, axis=0), LINEAR) + np.float32(1e-4)
                then = cv2.LUT(reference.reshape(-1, 3).take(usable, axis=0), LINEAR) + np.float32(1e-4)
                level = _brightness_ratio(now, then)
                lit = (level > FLOOR_BAND[0] * self.level) & (level < FLOOR_BAND[1] * self.level)
                if int(np.count_nonzero(lit)) >= 8:
                    ratio = now / then
                    if not lit.all():
                        ratio = ratio[lit]
                    light = [a * float(b) for a, b in zip(coarse, _column_medians(ratio), strict=True)]
                    total = max(sum(light), 1e-9)
                    if max(abs(v / total - w) for v, w in zip(light, self.white, strict=True)) > MAX_LIGHT_SHIFT:
                        light = viewed  # no light has that colour: something other than floor held the border
        total = max(sum(light), 1e-9)
        gains = [float(w) / max(v / total, 1e-6) for w, v in zip(self.white, light, strict=True)]
        scale = 3.0 / sum(gains)
        return np.array([min(max(g * scale, 1.0 / MAX_GAIN), MAX_GAIN) for g in gains])

    def frame_gains(self, shape_hw: tuple[int, int]) -> NDArray[np.float32]:
        """(h, w, 3) gains over a whole (downscaled) frame from the light map changed as the whole view has
        (:meth:`observe`; the acquisition pass: a lost rover is looked for under the white balance of now, not of
        the reference's last refresh)."""
        gains = self.white / np.maximum(self.light * np.asarray(self.change), 1e-6)
        gains /= gains.mean(axis=2, keepdims=True)
        gains = np.clip(gains, 1.0 / MAX_GAIN, MAX_GAIN).astype(np.float32)
        return np.asarray(cv2.resize(gains, (shape_hw[1], shape_hw[0]), interpolation=cv2.INTER_LINEAR))

    @staticmethod
    def correct(crop: U8, gains: FloatArray | NDArray[np.float32]) -> U8:
        """``crop`` with each channel multiplied by ``gains`` ((3,) or per pixel) in linear light."""
        if gains.ndim == 1:
            g = gains.tolist()
            if max(abs(g[0] - 1.0), abs(g[1] - 1.0), abs(g[2] - 1.0)) <= 2e-3:
                return crop
            # One gain per channel: each output value depends on its input value alone, so a table per channel.
            table = encode_linear(_LINEAR_COLUMN * gains.astype(np.float32))
            return np.asarray(cv2.LUT(crop, table.reshape(1, 256, 3)), dtype=np.uint8)
        return encode_linear(linear_bgr(crop) * gains.astype(np.float32))


@lru_cache(maxsize=8)
def _grid_index(h: int, w: int) -> NDArray[np.intp]:
    """Flat indices of about :data:`VIEW_SAMPLES` pixels on a regular grid over an ``h`` x ``w`` image."""
    step = max(1, round((h * w / VIEW_SAMPLES) ** 0.5))
    rows, cols = np.arange(step // 2, h, step), np.arange(step // 2, w, step)
    return np.asarray((rows[:, None] * w + cols[None, :]).ravel(), dtype=np.intp)


@lru_cache(maxsize=256)
def _border_index(h: int, w: int, width: int = 2) -> NDArray[np.intp]:
    """Flat indices of the pixels of the ``width``-pixel frame round an ``h`` x ``w`` image (each once; all of them
    when it is no larger than the frame): one gather instead of four slices joined."""
    if h <= 2 * width or w <= 2 * width:
        return np.arange(h * w)
    grid = np.arange(h * w).reshape(h, w)
    return np.concatenate(
        [
            grid[:width].ravel(),
            grid[h - width :].ravel(),
            grid[width : h - width, :width].ravel(),
            grid[width : h - width, w - width :].ravel(),
        ]
    )


def _inside(
    index: NDArray[np.intp], width: int, box: tuple[int, int, int, int], others: Sequence[tuple[int, int, int, int]]
) -> BoolArray:
    """Which of the window's pixels ``index`` (flat, ``width`` pixels a row; the window at ``box`` in the image) lie
    in any of the image boxes ``others``."""
    u = index % width + box[0]
    v = index // width + box[1]
    hit = np.zeros(len(index), bool)
    for ox0, oy0, ox1, oy1 in others:
        if ox0 < box[2] and box[0] < ox1 and oy0 < box[3] and box[1] < oy1:
            hit |= (u >= ox0) & (u < ox1) & (v >= oy0) & (v < oy1)
    return hit


def _column_medians(values: FloatArray) -> FloatArray:
    """``np.median(values, axis=0)`` of an (n, 3) array, from each channel's sorted row (numpy's vectorised sort is
    quicker than its partition on a window's border, and its middle values are the same)."""
    rows = np.sort(values.T, axis=1)
    k = rows.shape[1] // 2
    if rows.shape[1] % 2:
        return np.asarray(rows[:, k])
    return np.asarray(0.5 * (rows[:, k - 1] + rows[:, k]))


def _brightness_ratio(now: NDArray[np.float32], then: NDArray[np.float32]) -> NDArray[np.float32]:
    """(n,) each pixel's brightness (its linear channels' sum) now over then (a product with ones: a sum along the
    short axis costs twice as much)."""
    return np.asarray((now @ _ONES) / (then @ _ONES))


def _mean_colour(image: U8, valid: BoolArray) -> FloatArray:
    lin = linear_bgr(image)
    sel = valid & (image.max(axis=2) < 250)  # clipped pixels have lost their colour
    if not sel.any():
        return np.ones(3)
    return np.asarray(lin[sel].mean(axis=0), dtype=np.float64)


def _chromaticity(colour: FloatArray) -> FloatArray:
    c = np.asarray(colour, dtype=np.float64)
    return c / max(float(c.sum()), 1e-9)
