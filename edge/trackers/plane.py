"""The marker plane as the trackers see it: pixel <-> world mappings and the area centroid on the plane.

World position is the marker's *area* centroid on the marker plane, computed in the world, not in the image: the
pixel centroid of a blob is not the image of the marker's centre under perspective (a far-side marker is ~20 x 9
px and the scale changes across it). Each pixel's weight is multiplied by the world area it covers (the Jacobian
of the image-to-plane mapping) and the pixel centres are mapped to the plane before averaging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera
from edge.segmentation import F32, ramp

FloatArray = NDArray[np.float64]


@runtime_checkable
class PlaneMapping(Protocol):
    """Pixel <-> world on the marker plane: what the tracker needs from a calibration.

    ``edge.calibration.Calibration`` satisfies it. Both take and return (N, 2) float64 arrays (pixels: distorted
    image coordinates, pixel centres at integers; world: cm on the calibration plane).
    """

    def pixel_to_world(self, uv_px: FloatArray) -> FloatArray: ...

    def world_to_pixel(self, xy_cm: FloatArray) -> FloatArray: ...


@runtime_checkable
class WithWorkingArea(Protocol):
    """A mapping that knows the working area, ``(x0, y0, x1, y1)`` cm (optional: check with ``isinstance``;
    ``edge.calibration.Calibration`` does, a bare camera model does not)."""

    area_cm: tuple[float, float, float, float]


@dataclass(frozen=True)
class LocalPlaneMap:
    """The image-to-plane mapping of one :class:`PlaneGrid` tile as a homography ``G`` (world ~ G @ (u, v, 1)),
    for point queries near it: a search window's placement, a kernel's shape, a measurement's Jacobian."""

    g: FloatArray
    det: float
    g_inv: FloatArray

    def to_pixel(self, x_cm: FloatArray, y_cm: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Plane points back to pixels (the inverse homography)."""
        h = self.g_inv
        den = h[2, 0] * x_cm + h[2, 1] * y_cm + h[2, 2]
        return (h[0, 0] * x_cm + h[0, 1] * y_cm + h[0, 2]) / den, (h[1, 0] * x_cm + h[1, 1] * y_cm + h[1, 2]) / den

    def pixel_of(self, x_cm: float, y_cm: float) -> tuple[float, float, float, float]:
        """Pixel ``(u, v)`` of a plane point and the pixels per cm there along image u and v (half-widths of the
        image of a 1 cm circle), in plain floats: cheap enough to place every search window every frame."""
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = self._g_inv_floats
        den = (h20 * x_cm + h21 * y_cm + h22) or math.nan  # on the horizon: no pixel (floats do not divide by 0)
        u = (h00 * x_cm + h01 * y_cm + h02) / den
        v = (h10 * x_cm + h11 * y_cm + h12) / den
        j00, j01 = (h00 - u * h20) / den, (h01 - u * h21) / den
        j10, j11 = (h10 - v * h20) / den, (h11 - v * h21) / den
        return float(u), float(v), math.hypot(j00, j01), math.hypot(j10, j11)

    def jacobian(self, u: float, v: float) -> FloatArray:
        """(2, 2) d(x, y)/d(u, v) in cm per pixel at one pixel."""
        g00, g01, g02, g10, g11, g12, g20, g21, g22 = self._g_floats
        den = (g20 * u + g21 * v + g22) or math.nan  # on the horizon: no Jacobian
        x = (g00 * u + g01 * v + g02) / den
        y = (g10 * u + g11 * v + g12) / den
        return np.array(
            [
                [(g00 - x * g20) / den, (g01 - x * g21) / den],
                [(g10 - y * g20) / den, (g11 - y * g21) / den],
            ]
        )

    # The matrices' entries as plain floats: the same arithmetic as on numpy scalars, several times quicker.
    @cached_property
    def _g_floats(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.g.ravel())

    @cached_property
    def _g_inv_floats(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.g_inv.ravel())

    def area_at(self, u: float, v: float) -> float:
        """World cm^2 covered by the pixel at ``(u, v)``: :meth:`area_per_pixel` of one pixel, in plain floats."""
        _, _, _, _, _, _, g20, g21, g22 = self._g_floats
        return abs(self.det) / abs(g20 * u + g21 * v + g22) ** 3

    def to_world(self, u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        g = self.g
        den = g[2, 0] * u + g[2, 1] * v + g[2, 2]
        return (g[0, 0] * u + g[0, 1] * v + g[0, 2]) / den, (g[1, 0] * u + g[1, 1] * v + g[1, 2]) / den

    def area_per_pixel(self, u: FloatArray, v: FloatArray) -> FloatArray:
        """World cm^2 covered by the pixel at ``(u, v)``: ``|det G| / den^3`` (the homography's Jacobian)."""
        g = self.g
        den = g[2, 0] * u + g[2, 1] * v + g[2, 2]
        return np.asarray(abs(self.det) / np.abs(den) ** 3)


class PlaneGrid:
    """The calibration's pixel-to-plane mapping as one small homography per 8 x 8 pixel tile.

    The calibration is evaluated once at the tile corners (a few thousand points, one vectorised call); each tile
    then maps its pixels with the homography through its four corners. That is exact for a plane homography and
    follows lens distortion to a few thousandths of a centimetre, where one homography per window would be off by
    tenths of a pixel near the image edges. Mapping a pixel is a handful of multiplications, so the centroid of
    every marker pixel can be taken on the plane itself. Tiles with a corner off the plane (above the horizon) are
    invalid.
    """

    def __init__(self, mapping: PlaneMapping, size_wh: tuple[int, int], tile_px: int = 8) -> None:
        self.mapping = mapping
        self.tile_px = t = tile_px
        width, height = size_wh
        self.n_u = nu = math.ceil(width / t)
        self.n_v = nv = math.ceil(height / t)
        us = np.arange(nu + 1, dtype=np.float64) * t
        vs = np.arange(nv + 1, dtype=np.float64) * t
        grid_u, grid_v = np.meshgrid(us, vs)
        with np.errstate(all="ignore"):
            xy = np.asarray(mapping.pixel_to_world(np.column_stack([grid_u.ravel(), grid_v.ravel()])), np.float64)
        xy = xy.reshape(nv + 1, nu + 1, 2)
        c00, c10, c11, c01 = xy[:-1, :-1], xy[:-1, 1:], xy[1:, 1:], xy[1:, :-1]
        self.origin = c00.reshape(-1, 2).copy()  # world of each tile's top-left corner
        corners = np.stack([c00, c10, c11, c01], axis=2).reshape(-1, 4, 2) - self.origin[:, None, :]
        self.valid = np.all(np.isfinite(corners), axis=(1, 2))
        corners[~self.valid] = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
        src = np.array([[0.0, 0.0], [t, 0.0], [t, t], [0.0, t]])
        a = np.zeros((corners.shape[0], 8, 8))
        b = np.zeros((corners.shape[0], 8))
        for k, (du, dv) in enumerate(src):
            x, y = corners[:, k, 0], corners[:, k, 1]
            a[:, 2 * k, 0:3] = (du, dv, 1.0)
            a[:, 2 * k, 6] = -du * x
            a[:, 2 * k, 7] = -dv * x
            a[:, 2 * k + 1, 3:6] = (du, dv, 1.0)
            a[:, 2 * k + 1, 6] = -du * y
            a[:, 2 * k + 1, 7] = -dv * y
            b[:, 2 * k], b[:, 2 * k + 1] = x, y
        with np.errstate(all="ignore"):
            self.h: FloatArray = np.asarray(np.linalg.solve(a, b[..., None])[..., 0], np.float64)  # (tiles, 8)
        h = self.h
        self.det = h[:, 0] * (h[:, 4] - h[:, 5] * h[:, 7]) - h[:, 1] * (h[:, 3] - h[:, 5] * h[:, 6])
        self.det += h[:, 2] * (h[:, 3] * h[:, 7] - h[:, 4] * h[:, 6])
        self.valid &= np.isfinite(self.det) & (self.det != 0.0)
        self._local: dict[int, LocalPlaneMap | None] = {}
        # Every pixel's plane position and area, once: a window's centroid is then dense sums over slices.
        # Evaluated tile by tile with broadcasting: (tile rows, tile cols, 8, 8) pixels, no per-pixel gather.
        hh = self.h.reshape(nv, nu, 8)
        d = np.arange(t, dtype=np.float64)
        du, dv = d[None, None, None, :], d[None, None, :, None]

        def c(k: int) -> FloatArray:
            return hh[:, :, k, None, None]

        den = c(6) * du + c(7) * dv + 1.0
        origin = self.origin.reshape(nv, nu, 2)
        ok = self.valid.reshape(nv, nu)[:, :, None, None]
        xs = np.where(ok, origin[:, :, 0, None, None] + (c(0) * du + c(1) * dv + c(2)) / den, 0.0)
        ys = np.where(ok, origin[:, :, 1, None, None] + (c(3) * du + c(4) * dv + c(5)) / den, 0.0)
        areas = np.where(ok, np.abs(self.det.reshape(nv, nu)[:, :, None, None]) / np.abs(den) ** 3, 0.0)

        def image(a: FloatArray) -> FloatArray:
            return np.ascontiguousarray(a.transpose(0, 2, 1, 3).reshape(nv * t, nu * t)[:height, :width])

        # x and y as the planes of one (2, h, w) array: a window's offsets from a point are then one subtraction
        self.xy_cm: FloatArray = np.stack([image(xs), image(ys)])
        self.x_cm, self.y_cm, self.area_cm2 = self.xy_cm[0], self.xy_cm[1], image(areas)

    def pixels_of(self, area_cm2: float, u: float, v: float) -> float:
        """How many image pixels ``area_cm2`` of the plane covers at pixel ``(u, v)`` (inf off the plane)."""
        h, w = self.area_cm2.shape
        per_pixel = float(self.area_cm2[min(max(int(v), 0), h - 1), min(max(int(u), 0), w - 1)])
        return area_cm2 / per_pixel if per_pixel > 0.0 else math.inf

    def tile_of(self, u: float, v: float) -> int | None:
        if not (math.isfinite(u) and math.isfinite(v)):
            return None
        j = min(max(int(u // self.tile_px), 0), self.n_u - 1)
        i = min(max(int(v // self.tile_px), 0), self.n_v - 1)
        k = i * self.n_u + j
        return k if self.valid[k] else None

    def at(self, u: float, v: float) -> LocalPlaneMap | None:
        """The homography of the tile holding pixel ``(u, v)`` as a :class:`LocalPlaneMap`, or None off the plane."""
        k = self.tile_of(u, v)
        if k is None:
            return None
        if k not in self._local:
            h = self.h[k]
            t = self.tile_px
            u0, v0 = (k % self.n_u) * t, (k // self.n_u) * t
            hl = np.array([[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], 1.0]])
            to_local = np.array([[1.0, 0.0, -u0], [0.0, 1.0, -v0], [0.0, 0.0, 1.0]])
            from_local = np.array([[1.0, 0.0, self.origin[k, 0]], [0.0, 1.0, self.origin[k, 1]], [0.0, 0.0, 1.0]])
            g = from_local @ hl @ to_local
            self._local[k] = LocalPlaneMap(g, float(np.linalg.det(g)), np.asarray(np.linalg.inv(g)))
        return self._local[k]

    def map_pixels(self, u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
        """World ``x, y`` cm, world area per pixel (cm^2) and validity of pixels ``(u, v)`` (integer centres)."""
        t = self.tile_px
        j = np.clip((u // t).astype(np.intp), 0, self.n_u - 1)
        i = np.clip((v // t).astype(np.intp), 0, self.n_v - 1)
        k = i * self.n_u + j
        du = u - j * t
        dv = v - i * t
        h = self.h[k]
        den = h[:, 6] * du + h[:, 7] * dv + 1.0
        x = self.origin[k, 0] + (h[:, 0] * du + h[:, 1] * dv + h[:, 2]) / den
        y = self.origin[k, 1] + (h[:, 3] * du + h[:, 4] * dv + h[:, 5]) / den
        area = np.abs(self.det[k]) / np.abs(den) ** 3
        return x, y, area, self.valid[k]


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


SHAPE_RECHECK = 1.5  # a blob more elongated has its shape taken again without its coverage's negative shares


def shape_elongation(weights: F32, offset_xy: tuple[int, int], grid: PlaneGrid, blob: WorldBlob) -> float:
    """The elongation the shape checks read for ``blob`` (:func:`world_blob` of ``weights``): over
    :data:`SHAPE_RECHECK`, that of the weights without their negative shares. The coverage keeps shares down to -0.5
    so that noise beyond the edge averages out of the centre; but rows of them beside its long sides (a rim the
    surround's colours miss, in a flicker band's phase) are no part of the marker's shape, and their second moments,
    taken off the marker's, made a whole marker's elongation 2-3 or infinite (the family's drift clip, seed 14641 on
    wood: a blue marker on a white body refused in every third frame)."""
    if blob.elongation <= SHAPE_RECHECK or float(weights.min()) >= 0.0:
        return blob.elongation
    shape = world_blob(np.maximum(weights, 0.0), offset_xy, grid)
    return blob.elongation if shape is None else shape.elongation


def world_blob(weights: F32, offset_xy: tuple[int, int], grid: PlaneGrid) -> WorldBlob | None:
    """Area centroid on the world plane of a weighted window (eq. 3-4 with perspective done right).

    ``weights``: (h, w) float32 coverage of each pixel by the marker (0 outside, 1 inside, fractions at the
    edge); ``offset_xy``: the window's top-left pixel in the image. Each pixel contributes its coverage times
    the world area it spans, at its centre mapped to the plane. Returns None when the weights sum to nothing.
    """
    bx, by, w, h = cv2.boundingRect((weights != 0).view(np.uint8))
    if w == 0 or h == 0:
        return None
    wt = weights[by : by + h, bx : bx + w].astype(np.float64)  # one contiguous copy: no mixed types below
    x0, y0 = offset_xy[0] + bx, offset_xy[1] + by
    rows, cols = slice(y0, y0 + h), slice(x0, x0 + w)
    jw = (wt * grid.area_cm2[rows, cols]).ravel()  # zero off the plane
    total = float(jw.sum())
    (wsum, u_sum), (v_sum, _) = (ramp(h).T @ wt @ ramp(w)).tolist()  # the image centroid's sums
    if total <= 1e-9 or wsum <= 1e-9:
        return None
    # Moments about a point inside the window keep the sums well conditioned (a blob spans a few tens of cm); each
    # sum over the pixels is one product with the (2, n) offsets.
    xy = grid.xy_cm[:, rows, cols]
    centre = xy[:, h // 2, w // 2]
    d = (xy - centre[:, None, None]).reshape(2, -1)
    mx, my = (d @ jw / total).tolist()
    (sxx, sxy), (_, syy) = ((d * jw) @ d.T / total).tolist()
    ox, oy = centre.tolist()
    cov = (sxx - mx * mx, sxy - mx * my, syy - my * my)
    return WorldBlob(ox + mx, oy + my, total, x0 + u_sum / wsum, y0 + v_sum / wsum, cov)


@dataclass(frozen=True)
class CameraPlaneMapping:
    """A :class:`PlaneMapping` straight from a known camera (the simulator's ``camera.json``): exact, no fit."""

    camera: PinholeCamera
    plane_height_cm: float = 13.0

    def pixel_to_world(self, uv_px: FloatArray) -> FloatArray:
        """(N, 2) pixels -> (N, 2) plane cm; NaN for rays that meet the plane behind the camera."""
        with np.errstate(all="ignore"):
            xy = self.camera.pixel_to_plane(np.asarray(uv_px, dtype=np.float64).reshape(-1, 2), self.plane_height_cm)
        xyz = np.column_stack([xy, np.full(len(xy), self.plane_height_cm)])
        ok = np.all(np.isfinite(xy), axis=1)
        ok[ok] = self.camera.in_front(xyz[ok])
        return np.where(ok[:, None], xy, np.nan)

    def world_to_pixel(self, xy_cm: FloatArray) -> FloatArray:
        xy = np.asarray(xy_cm, dtype=np.float64).reshape(-1, 2)
        return self.camera.project(np.column_stack([xy, np.full(len(xy), self.plane_height_cm)]))

    @property
    def image_size(self) -> tuple[int, int]:
        return self.camera.width_px, self.camera.height_px
