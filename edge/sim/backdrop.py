"""The static floor as the camera sees it, rendered once per scene and camera.

For every pixel the ray through it (lens distortion undone) is met with the floor plane; the floor's albedo
(:class:`edge.sim.scene.FloorTexture`) is supersampled ``supersample x supersample`` times per pixel and box-filtered
(as a sensor pixel integrates), the smooth lighting terms (lamp irradiance, lamp reflections in the glossy floor,
vignetting) are evaluated once per pixel. The results, in linear light units of the nominal exposure:

* ``room``: (H, W, 3) the lit floor;
* ``illumination``: (H, W) lamp irradiance x vignetting x exposure scale, used to light rovers and people;
* ``vignetting``: (H, W);
* ``sun``: (H, W, 3) floor albedo x sunlit fraction x vignetting x exposure scale (times beam strength and colour
  per frame), or None;
* ``glare``: (H, W) glare shape x vignetting x exposure scale, or None.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import overload

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera
from edge.sim.effects import Effects, Glare, SunPatch, Vignetting, vignetting_map
from edge.sim.scene import FloorTexture, Scene, lamp_reflection, room_irradiance

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]


@dataclass(frozen=True)
class Backdrop:
    room: F32
    illumination: F32
    vignetting: F32
    sun: F32 | None
    glare: F32 | None
    sun_mean_ratio: float


def pixel_floor_points(camera: PinholeCamera, uv_px: FloatArray, z_cm: float = 0.0) -> FloatArray:
    """(N, 2) world x, y where the rays of (N, 2) distorted pixels meet the plane z = ``z_cm`` (NaN if they miss)."""
    ideal = camera.undistort_px(uv_px)
    # ray_world = R^T K^-1 (u, v, 1): written out per column (a skinny matrix product is slow in BLAS).
    m = camera.rotation.T @ np.linalg.inv(camera.camera_matrix)
    u, v = ideal[:, 0], ideal[:, 1]
    rx = m[0, 0] * u + m[0, 1] * v + m[0, 2]
    ry = m[1, 0] * u + m[1, 1] * v + m[1, 2]
    rz = m[2, 0] * u + m[2, 1] * v + m[2, 2]
    centre = camera.position_cm
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z_cm - centre[2]) / rz
    xy = np.column_stack([centre[0] + rx * s, centre[1] + ry * s])
    xy[~(s > 0)] = np.nan  # rays that never meet the plane in front of the camera
    return xy


_CACHE: OrderedDict[tuple[object, ...], Backdrop] = OrderedDict()
_CACHE_SIZE = 6


def prerender(camera: PinholeCamera, scene: Scene, effects: Effects, supersample: int = 2) -> Backdrop:
    """The static floor of ``scene`` seen by ``camera`` (cached: several renderers of one scene share it)."""
    key = (
        camera.camera_matrix.tobytes(),
        camera.dist_coeffs.tobytes(),
        camera.rvec.tobytes(),
        camera.tvec.tobytes(),
        camera.width_px,
        camera.height_px,
        scene.floor,
        scene.tape,
        scene.lamps,
        scene.ambient,
        scene.lamp_luminance,
        scene.texture_seed,
        effects.exposure.scale,
        effects.vignetting,
        effects.sun,
        effects.glare,
        effects.optics,
        supersample,
    )
    found = _CACHE.get(key)
    if found is not None:
        _CACHE.move_to_end(key)
        return found
    psf = effects.optics.blur_sigma_px if effects.optics is not None else 0.0
    made = _render(
        camera, scene, effects.exposure.scale, effects.vignetting, effects.sun, effects.glare, supersample, psf
    )
    _CACHE[key] = made
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return made


def _render(
    camera: PinholeCamera,
    scene: Scene,
    exposure_scale: float,
    vignetting: Vignetting | None,
    sun: SunPatch | None,
    glare: Glare | None,
    ss: int,
    psf_sigma_px: float,
) -> Backdrop:
    h, w = camera.height_px, camera.width_px
    texture = FloorTexture(scene.floor, scene.tape, scene.texture_seed)
    vig = vignetting_map(camera.camera_matrix, w, h, vignetting).astype(np.float32)

    # Per-pixel floor points (pixel centres) and their local Jacobian, for supersampling and lighting.
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = pixel_floor_points(camera, np.column_stack([uu.ravel(), vv.ravel()])).reshape(h, w, 2)
    dxy_du: FloatArray = np.asarray(np.gradient(xy, axis=1))
    dxy_dv: FloatArray = np.asarray(np.gradient(xy, axis=0))
    valid: NDArray[np.bool_] = np.asarray(np.isfinite(xy).all(axis=2))
    xy_safe = np.where(valid[..., None], xy, 0.0)

    # Albedo: ss x ss samples per pixel, each a box of the sub-sample's footprint.
    footprint = np.sqrt(np.abs(dxy_du[..., 0] * dxy_dv[..., 1] - dxy_du[..., 1] * dxy_dv[..., 0])) / ss
    footprint = np.where(np.isfinite(footprint), np.maximum(footprint, 1e-3), 1.0)
    albedo = np.zeros((h, w, 3))
    sun_cover = np.zeros((h, w, 3)) if sun is not None else None
    sun_lit = np.zeros((h, w))
    sun_poly = sun.patch_cm(0.0) if sun is not None else None
    offsets = (np.arange(ss) + 0.5) / ss - 0.5
    for oy in offsets:
        for ox in offsets:
            p = xy_safe + dxy_du * ox + dxy_dv * oy
            flat = np.nan_to_num(p.reshape(-1, 2))
            a = texture.albedo(flat, footprint.ravel()).reshape(h, w, 3)
            albedo += a
            if sun_cover is not None and sun_poly is not None and sun is not None:
                lit = _soft_convex(flat, sun_poly, sun.penumbra_cm).reshape(h, w)
                sun_cover += a * lit[..., None]
                sun_lit += lit
    albedo /= ss * ss
    flat_xy = xy_safe.reshape(-1, 2)
    irradiance = room_irradiance(flat_xy, scene.lamps, scene.ambient).reshape(h, w)
    reflection = lamp_reflection(flat_xy, camera.position_cm, scene.lamps, scene.floor, scene.lamp_luminance)
    reflection = reflection.reshape(h, w)
    wall = np.array([0.30, 0.31, 0.32])  # beyond the floor's horizon (not seen by the default cameras)
    room = albedo * irradiance[..., None] + reflection[..., None] * np.array([0.97, 1.0, 1.0])
    room = np.where(valid[..., None], room, wall)
    gain = vig.astype(np.float64) * exposure_scale
    room_lin = (room * gain[..., None]).astype(np.float32)
    illum = (irradiance * gain).astype(np.float32)

    sun_lin = None
    ratio = 0.0
    if sun_cover is not None:
        sun_lin = (sun_cover / (ss * ss) * gain[..., None]).astype(np.float32)
        ratio = float(sun_lin.mean() / max(float(room_lin.mean()), 1e-9))
    glare_lin = None
    if glare is not None:
        lit_fraction = sun_lit / (ss * ss) if sun is not None else 1.0
        glare_lin = (_glare_shape(xy_safe, camera, glare) * lit_fraction * valid * gain).astype(np.float32)
    return Backdrop(
        _soften(room_lin, psf_sigma_px),
        illum,
        vig,
        _soften(sun_lin, psf_sigma_px),
        _soften(glare_lin, psf_sigma_px),
        ratio,
    )


@overload
def _soften(image: F32, sigma_px: float) -> F32: ...
@overload
def _soften(image: None, sigma_px: float) -> None: ...
def _soften(image: F32 | None, sigma_px: float) -> F32 | None:
    """The optics' point spread over a prerendered layer (in linear light, as a lens blurs light)."""
    if image is None or sigma_px < 0.05:
        return image
    return np.asarray(cv2.GaussianBlur(image, (0, 0), sigma_px), dtype=np.float32)


def _soft_convex(xy_cm: FloatArray, polygon_cm: FloatArray, blur_cm: float) -> FloatArray:
    """Smooth inside-indicator of a convex polygon (edges blurred over ``blur_cm``: the sun's penumbra)."""
    poly = np.asarray(polygon_cm, dtype=np.float64)
    area = 0.5 * np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    if area < 0:
        poly = poly[::-1]
    inside = np.ones(len(xy_cm))
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        edge = b - a
        normal = np.array([-edge[1], edge[0]]) / np.hypot(*edge)  # inward for counter-clockwise polygons
        dist = (xy_cm - a) @ normal
        inside *= np.clip(dist / max(blur_cm, 1e-6) + 0.5, 0.0, 1.0)
    return inside


def _glare_shape(xy: FloatArray, camera: PinholeCamera, glare: Glare) -> FloatArray:
    """(H, W) glare intensity: a bright core with a halo, stretched along the camera's line of sight."""
    c = camera.position_cm
    view = np.array([glare.x_cm - c[0], glare.y_cm - c[1]])
    view /= np.linalg.norm(view)
    across = np.array([-view[1], view[0]])
    d = xy - np.array([glare.x_cm, glare.y_cm])
    a = (d @ view) / (glare.radius_cm * glare.elongation)
    b = (d @ across) / glare.radius_cm
    r2 = a * a + b * b
    return np.asarray(glare.peak * (np.exp(-r2 * 2.0) + 0.15 * np.exp(-r2 * 0.25)))


def encode_linear(lin: F32, gamma: float, headroom: float) -> NDArray[np.uint16]:
    """Linear light (0..headroom) to the 16-bit tone-curve code the renderer keeps its working image in."""
    x = np.clip(lin / headroom, 0.0, 1.0)
    return np.asarray(np.rint(np.power(x, 1.0 / gamma) * 65535.0), dtype=np.uint16)
