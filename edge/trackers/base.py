"""What every tracker shares: the calibration it maps through, the window it measures in, what it returns.

A tracker here measures ONE rover in a small full-resolution window around where the rover is predicted to be.
The pipeline (``edge.pipeline``) prepares the window once (colour planes, hue classes, background subtraction)
and the tracker turns it into a :class:`Measurement` in world centimetres.

World position is the marker's *area* centroid on the marker plane, computed in the world, not in the image: the
pixel centroid of a blob is not the image of the marker's centre under perspective (a far-side marker is ~20 x 9
px and the scale changes across it). Each pixel's weight is multiplied by the world area it covers (the Jacobian
of the image-to-plane mapping) and the pixel centres are mapped to the plane before averaging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera
from edge.segmentation import F32, U8, BoolArray

FloatArray = NDArray[np.float64]


@runtime_checkable
class PlaneMapping(Protocol):
    """Pixel <-> world on the marker plane: what the tracker needs from a calibration.

    ``edge.calibration.Calibration`` satisfies it. Both take and return (N, 2) float64 arrays (pixels: distorted
    image coordinates, pixel centres at integers; world: cm on the calibration plane).
    """

    def pixel_to_world(self, uv_px: FloatArray) -> FloatArray: ...

    def world_to_pixel(self, xy_cm: FloatArray) -> FloatArray: ...


class StageClock(Protocol):
    """Accumulates the time of named stages (Table IV rows). ``edge.pipeline.StageTimes`` implements it."""

    def add(self, stage: str, seconds: float) -> None: ...


class NullClock:
    """A :class:`StageClock` that records nothing."""

    def add(self, stage: str, seconds: float) -> None:
        return None


@dataclass(frozen=True)
class LocalPlaneMap:
    """The image-to-plane mapping near one window, as a homography ``G`` (world ~ G @ (u, v, 1)).

    Fitted to the calibration at a 3x3 grid of points over the window: exact for a plane homography, and for a
    lens-distorted calibration the residual over a window of a hundred pixels is a few thousandths of a pixel.
    """

    g: FloatArray
    det: float
    g_inv: FloatArray

    @classmethod
    def fit(cls, mapping: PlaneMapping, box: tuple[int, int, int, int]) -> LocalPlaneMap:
        x0, y0, x1, y1 = box
        us = np.linspace(x0 - 0.5, x1 - 0.5, 3)
        vs = np.linspace(y0 - 0.5, y1 - 0.5, 3)
        uv = np.array([(u, v) for v in vs for u in us], dtype=np.float64)
        xy = np.asarray(mapping.pixel_to_world(uv), dtype=np.float64)
        if not np.all(np.isfinite(xy)):
            raise ValueError(f"calibration gives no plane mapping near pixels {box}")
        g, _ = cv2.findHomography(uv, xy, 0)
        if g is None or not np.all(np.isfinite(g)):
            raise ValueError(f"calibration gives no plane mapping near pixels {box}")
        g64 = np.asarray(g, dtype=np.float64)
        return cls(g64, float(np.linalg.det(g64)), np.asarray(np.linalg.inv(g64)))

    def to_pixel(self, x_cm: FloatArray, y_cm: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Plane points back to pixels (the inverse homography)."""
        h = self.g_inv
        den = h[2, 0] * x_cm + h[2, 1] * y_cm + h[2, 2]
        return (h[0, 0] * x_cm + h[0, 1] * y_cm + h[0, 2]) / den, (h[1, 0] * x_cm + h[1, 1] * y_cm + h[1, 2]) / den

    def jacobian(self, u: float, v: float) -> FloatArray:
        """(2, 2) d(x, y)/d(u, v) in cm per pixel at one pixel."""
        g = self.g
        den = g[2, 0] * u + g[2, 1] * v + g[2, 2]
        x = (g[0, 0] * u + g[0, 1] * v + g[0, 2]) / den
        y = (g[1, 0] * u + g[1, 1] * v + g[1, 2]) / den
        return np.array(
            [
                [(g[0, 0] - x * g[2, 0]) / den, (g[0, 1] - x * g[2, 1]) / den],
                [(g[1, 0] - y * g[2, 0]) / den, (g[1, 1] - y * g[2, 1]) / den],
            ]
        )

    def to_world(self, u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        g = self.g
        den = g[2, 0] * u + g[2, 1] * v + g[2, 2]
        return (g[0, 0] * u + g[0, 1] * v + g[0, 2]) / den, (g[1, 0] * u + g[1, 1] * v + g[1, 2]) / den

    def area_per_pixel(self, u: FloatArray, v: FloatArray) -> FloatArray:
        """World cm^2 covered by the pixel at ``(u, v)``: ``|det G| / den^3`` (the homography's Jacobian)."""
        g = self.g
        den = g[2, 0] * u + g[2, 1] * v + g[2, 2]
        return np.asarray(abs(self.det) / np.abs(den) ** 3)


class PlaneMapCache:
    """Local plane maps per image tile, fitted once: windows reuse the map of the tile their centre falls in.

    Each map is fitted over its tile grown by one tile on every side, so any window centred in the tile lies in
    the fitted region (exact for a plane homography; for a distorted lens the residual over 3 x 64 px is far below
    the measurement noise).
    """

    def __init__(self, mapping: PlaneMapping, tile_px: int = 64) -> None:
        self.mapping = mapping
        self.tile_px = tile_px
        self._maps: dict[tuple[int, int], LocalPlaneMap | None] = {}

    def at(self, u: float, v: float) -> LocalPlaneMap | None:
        """The local map around pixel ``(u, v)``, or None where the calibration has no mapping."""
        if not (math.isfinite(u) and math.isfinite(v)):
            return None
        t = self.tile_px
        key = (math.floor(u / t), math.floor(v / t))
        if key not in self._maps:
            box = ((key[0] - 1) * t, (key[1] - 1) * t, (key[0] + 2) * t, (key[1] + 2) * t)
            try:
                self._maps[key] = LocalPlaneMap.fit(self.mapping, box)
            except ValueError:
                self._maps[key] = None
        return self._maps[key]


@dataclass(frozen=True)
class WorldBlob:
    """Weighted pixels mapped to the plane: area centroid, area and second moments in world units."""

    x_cm: float
    y_cm: float
    area_cm2: float
    u_px: float
    v_px: float
    cov_cm2: tuple[float, float, float]  # xx, xy, yy

    @property
    def axis_rad(self) -> float:
        """Orientation of the blob's long axis in the world, modulo pi."""
        xx, xy, yy = self.cov_cm2
        return 0.5 * math.atan2(2.0 * xy, xx - yy)

    @property
    def elongation(self) -> float:
        """Ratio of the principal standard deviations (1 for a square or a disc)."""
        xx, xy, yy = self.cov_cm2
        tr, det = xx + yy, xx * yy - xy * xy
        disc = math.sqrt(max(tr * tr / 4.0 - det, 0.0))
        small = tr / 2.0 - disc
        return math.sqrt((tr / 2.0 + disc) / small) if small > 1e-12 else math.inf


def world_blob(weights: F32, offset_xy: tuple[int, int], local: LocalPlaneMap) -> WorldBlob | None:
    """Area centroid on the world plane of a weighted window (eq. 3-4 with perspective done right).

    ``weights``: (h, w) float32 coverage of each pixel by the marker (0 outside, 1 inside, fractions at the
    edge); ``offset_xy``: the window's top-left pixel in the image. Each pixel contributes its coverage times
    the world area it spans, at its centre mapped to the plane. Returns None when the weights sum to nothing.
    """
    vs, us = np.nonzero(weights)
    if us.size == 0:
        return None
    w = weights[vs, us].astype(np.float64)
    u = us.astype(np.float64) + offset_xy[0]
    v = vs.astype(np.float64) + offset_xy[1]
    jw = w * local.area_per_pixel(u, v)
    total = float(jw.sum())
    if total <= 1e-9:
        return None
    x, y = local.to_world(u, v)
    cx, cy = float(jw @ x) / total, float(jw @ y) / total
    dx, dy = x - cx, y - cy
    cov = (float(jw @ (dx * dx)) / total, float(jw @ (dx * dy)) / total, float(jw @ (dy * dy)) / total)
    wsum = float(w.sum())
    return WorldBlob(cx, cy, total, float(w @ u) / wsum, float(w @ v) / wsum, cov)


@dataclass
class Window:
    """One rover's full-resolution search window, prepared once by the pipeline for the tracker.

    ``box``: ``(x0, y0, x1, y1)`` in the image (exclusive ends). ``bgr``: the (h, w, 3) crop (a view of the
    frame). ``c1``, ``c2``, ``lum``: opponent chroma and luminance (float32). ``classes``: (h, w) int16 rover
    index per pixel from the hue table (-1: none). ``plane``: the rover's colour plane (chroma projected on its
    hue). ``foreground``: eq. 2 against the background model (False where the reference is not yet valid).
    ``reference_valid``: where the background reference is trustworthy. ``local``: the plane mapping here.
    ``predicted_uv``: where the filter expects the marker centre, in image pixels.
    """

    box: tuple[int, int, int, int]
    bgr: U8
    c1: F32
    c2: F32
    lum: F32
    classes: NDArray[np.int16]
    plane: F32
    foreground: BoolArray
    reference_valid: BoolArray
    local: LocalPlaneMap
    predicted_uv: tuple[float, float]

    @property
    def offset(self) -> tuple[int, int]:
        return self.box[0], self.box[1]


@dataclass(frozen=True)
class RoverModel:
    """What a tracker knows about the rover it measures (mutable state stays in the pipeline).

    ``index``: the rover's index in the colour model. ``marker_area_cm2``: expected marker area on the plane.
    ``marker_level``: the marker's current value in its colour plane (for coverage weights), or 0 if unknown.
    """

    index: int
    marker_area_cm2: float
    marker_level: float


@dataclass(frozen=True)
class Measurement:
    """A tracker's measurement of one rover in one frame (before filtering).

    ``xy_cm``: marker centre on the plane; ``uv_px``: coverage-weighted image centroid; ``area_cm2``: measured
    marker area on the plane; ``level``: the marker's value in its colour plane (the next frame's threshold
    reference); ``quality`` 0..1; ``axis_rad``: long-axis orientation modulo pi; ``foreground_fraction``: share
    of its pixels that differ from the background reference (where valid).
    """

    xy_cm: tuple[float, float]
    uv_px: tuple[float, float]
    area_cm2: float
    level: float
    quality: float
    axis_rad: float
    foreground_fraction: float


class WindowTracker(Protocol):
    """Measures one rover inside its prepared window. Stateless between frames (state lives in the pipeline)."""

    name: str

    def measure(self, window: Window, rover: RoverModel, clock: StageClock) -> Measurement | None: ...


def area_quality(area_cm2: float, expected_cm2: float) -> float:
    """1 when the measured marker area is as expected, falling as it is smaller (occluded) or larger (merged)."""
    if expected_cm2 <= 0.0:
        return 1.0
    r = area_cm2 / expected_cm2
    return float(max(0.0, min(r, 1.0 / r if r > 0 else 0.0)))


@dataclass(frozen=True)
class CameraPlaneMapping:
    """A :class:`PlaneMapping` straight from a known camera (the simulator's ``camera.json``): exact, no fit."""

    camera: PinholeCamera
    plane_height_cm: float = 13.0

    def pixel_to_world(self, uv_px: FloatArray) -> FloatArray:
        return self.camera.pixel_to_plane(np.asarray(uv_px, dtype=np.float64).reshape(-1, 2), self.plane_height_cm)

    def world_to_pixel(self, xy_cm: FloatArray) -> FloatArray:
        xy = np.asarray(xy_cm, dtype=np.float64).reshape(-1, 2)
        return self.camera.project(np.column_stack([xy, np.full(len(xy), self.plane_height_cm)]))

    @property
    def image_size(self) -> tuple[int, int]:
        return self.camera.width_px, self.camera.height_px
