"""Small synthetic scenes for the tracking tests: the paper's camera, a tiled floor, dark rovers with markers.

Independent of the simulator (``edge.sim``) on purpose: the tracker's stages are tested on images whose ground
truth is built here, sub-pixel exact (rover regions are drawn at 8x and area-averaged down), with the effects a
real camera adds (gain changes, noise, motion blur, JPEG with 4:2:0 chroma).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import MARKER_HEIGHT_CM, PinholeCamera, paper_camera
from edge.tracker_config import RoverConfig
from edge.trackers.base import CameraPlaneMapping
from edge.tracking import Frame

U8 = NDArray[np.uint8]

# Marker colours as a camera sees printed markers: far from pure primaries.
COLORS = {
    "red": (50, 45, 190),
    "green": (70, 160, 50),
    "blue": (175, 95, 35),
    "yellow": (40, 175, 200),
    "magenta": (150, 55, 170),
    "cyan": (170, 160, 40),
}


@dataclass
class SynthRover:
    """A rover in the synthetic scene: marker centre ``(x, y)`` cm at marker height, heading ``theta`` rad."""

    id: str
    x: float
    y: float
    theta: float = 0.0
    color_bgr: tuple[int, int, int] = (50, 45, 190)
    marker_cm: tuple[float, float] = (22.0, 17.0)  # along heading, across
    body_cm: tuple[float, float] = (25.0, 20.0)
    front_color_bgr: tuple[int, int, int] | None = None  # two-tone: the front part of the marker
    front_fraction: float = 0.3
    visible: bool = True

    def config(self) -> RoverConfig:
        return RoverConfig(
            id=self.id,
            color_bgr=self.color_bgr,
            front_color_bgr=self.front_color_bgr,
            front_fraction=self.front_fraction,
        )


def _rect(cx: float, cy: float, theta: float, length: float, width: float, z: float) -> NDArray[np.float64]:
    c, s = math.cos(theta), math.sin(theta)
    half = [(length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2)]
    return np.array([[cx + a * c - b * s, cy + a * s + b * c, z] for a, b in half])


@dataclass
class Scene:
    """A static floor seen by ``camera`` and a way to draw rovers on it."""

    camera: PinholeCamera = field(default_factory=paper_camera)
    seed: int = 0
    floor: U8 = field(init=False)

    def __post_init__(self) -> None:
        self.floor = floor_image(self.camera, np.random.default_rng(self.seed))

    @property
    def mapping(self) -> CameraPlaneMapping:
        return CameraPlaneMapping(self.camera, MARKER_HEIGHT_CM)

    def render(
        self,
        rovers: list[SynthRover],
        *,
        gain: float = 1.0,
        noise_sigma: float = 0.0,
        rng: np.random.Generator | None = None,
        jpeg_quality: int | None = None,
        blur_cm: tuple[float, float] = (0.0, 0.0),
        supersample: int = 8,
        row_gain: NDArray[np.float32] | None = None,
        sun: tuple[tuple[int, int, int, int], tuple[float, float, float]] | None = None,
        glare: tuple[float, float, float] | None = None,
    ) -> U8:
        """One frame: the floor, the rovers (far ones first), then light, noise and compression.

        ``blur_cm``: marker displacement during the exposure (motion blur, drawn as 5 sub-exposures centred on
        the rover's position). ``row_gain``: (H,) per-row light level (rolling-shutter mains flicker). ``sun``:
        a pixel box ``(x0, y0, x1, y1)`` lit warmer and brighter by a BGR factor (a sunlit window patch).
        ``glare``: ``(u, v, radius_px)`` of a bright, desaturated specular spot.
        """
        img = self.floor.astype(np.float32)
        cam_pos = self.camera.position_cm
        order = sorted(rovers, key=lambda r: -math.hypot(r.x - cam_pos[0], r.y - cam_pos[1]))
        for rover in order:
            if not rover.visible:
                continue
            steps = [0.0] if blur_cm == (0.0, 0.0) else list(np.linspace(-0.5, 0.5, 5))
            acc = None
            box = None
            for f in steps:
                moved = SynthRover(**{**rover.__dict__, "x": rover.x + f * blur_cm[0], "y": rover.y + f * blur_cm[1]})
                drawn = _draw_rover(img, self.camera, moved, supersample, pad=8)
                if drawn is None:
                    break
                patch, box_f = drawn
                if acc is None:
                    acc, box = patch, box_f
                else:
                    acc += patch
            if acc is None or box is None:
                continue
            x0, y0, x1, y1 = box
            img[y0:y1, x0:x1] = acc / len(steps)
        img *= gain
        if row_gain is not None:
            img *= row_gain[:, None, None]
        if sun is not None:
            (x0, y0, x1, y1), factor = sun
            yy, xx = np.mgrid[y0:y1, x0:x1]
            soft = np.minimum.reduce([xx - x0, x1 - 1 - xx, yy - y0, y1 - 1 - yy]).astype(np.float32)
            ramp = np.clip(soft / 20.0, 0.0, 1.0)[..., None]
            img[y0:y1, x0:x1] *= 1.0 + ramp * (np.asarray(factor, np.float32) - 1.0)
        if glare is not None:
            gu, gv, gr = glare
            r = int(4 * gr) + 1
            y0, y1 = max(0, int(gv) - r), min(img.shape[0], int(gv) + r)
            x0, x1 = max(0, int(gu) - r), min(img.shape[1], int(gu) + r)
            yy, xx = np.mgrid[y0:y1, x0:x1]
            spot = np.exp(-((xx - gu) ** 2 + (yy - gv) ** 2) / (2.0 * gr * gr)).astype(np.float32)[..., None]
            img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1.0 - spot) + 250.0 * spot
        if noise_sigma > 0.0:
            rng = rng or np.random.default_rng(0)
            img += rng.normal(0.0, noise_sigma, img.shape).astype(np.float32) * np.sqrt(np.maximum(img, 1.0) / 128.0)
        out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        if jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            assert ok
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        return out


def _draw_rover(
    img: NDArray[np.float32], camera: PinholeCamera, rover: SynthRover, ss: int, pad: int
) -> tuple[NDArray[np.float32], tuple[int, int, int, int]] | None:
    """The rover drawn over ``img`` in its bounding box at ``ss`` x supersampling, area-averaged back."""
    bl, bw = rover.body_cm
    bottom = _rect(rover.x, rover.y, rover.theta, bl, bw, 0.0)
    top = _rect(rover.x, rover.y, rover.theta, bl, bw, MARKER_HEIGHT_CM - 0.01)
    uv_all = camera.project(np.vstack([bottom, top]))
    h, w = img.shape[:2]
    x0 = max(0, math.floor(uv_all[:, 0].min()) - pad)
    y0 = max(0, math.floor(uv_all[:, 1].min()) - pad)
    x1 = min(w, math.ceil(uv_all[:, 0].max()) + pad)
    y1 = min(h, math.ceil(uv_all[:, 1].max()) + pad)
    if x1 <= x0 or y1 <= y0:
        return None  # out of view
    base = img[y0:y1, x0:x1]
    big = cv2.resize(base, ((x1 - x0) * ss, (y1 - y0) * ss), interpolation=cv2.INTER_NEAREST)

    def fill(points_world: NDArray[np.float64], color: tuple[float, float, float]) -> None:
        uv = camera.project(points_world)
        big_uv = ((uv - [x0, y0] + 0.5) * ss - 0.5) * 16.0
        cv2.fillPoly(big, [np.rint(big_uv).astype(np.int32)], color, lineType=cv2.LINE_8, shift=4)

    # Shadow-free dark body: side faces (shaded by their direction), far sides first, then the top.
    cam = camera.position_cm
    faces = []
    for i in range(4):
        j = (i + 1) % 4
        quad = np.array([bottom[i], bottom[j], top[j], top[i]])
        centre = quad.mean(axis=0)
        faces.append((-float(np.linalg.norm(centre[:2] - cam[:2])), quad, 28.0 + 8.0 * i))
    for _, quad, shade in sorted(faces, key=lambda f: f[0]):
        fill(quad, (shade, shade, shade * 1.05))
    fill(top, (22.0, 22.0, 24.0))
    ml, mw = rover.marker_cm
    if rover.front_color_bgr is None:
        fill(_rect(rover.x, rover.y, rover.theta, ml, mw, MARKER_HEIGHT_CM), rover.color_bgr)
    else:
        c, s = math.cos(rover.theta), math.sin(rover.theta)
        f = rover.front_fraction
        front, rear = (0.5 - f / 2.0) * ml, -f / 2.0 * ml  # centres of the two parts along the heading
        fill(
            _rect(rover.x + front * c, rover.y + front * s, rover.theta, f * ml, mw, MARKER_HEIGHT_CM),
            rover.front_color_bgr,
        )
        fill(
            _rect(rover.x + rear * c, rover.y + rear * s, rover.theta, (1 - f) * ml, mw, MARKER_HEIGHT_CM),
            rover.color_bgr,
        )
    small = cv2.resize(big, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    return small.astype(np.float32), (x0, y0, x1, y1)


def floor_image(camera: PinholeCamera, rng: np.random.Generator) -> U8:
    """The floor seen by ``camera``: 30 cm tiles with grout and per-tile shade, a tape outline of the area."""
    px_per_cm = 2.0
    xmin, ymin, xmax, ymax = -260.0, -220.0, 660.0, 900.0
    tw, th = int((xmax - xmin) * px_per_cm), int((ymax - ymin) * px_per_cm)
    xs = xmin + (np.arange(tw) + 0.5) / px_per_cm
    ys = ymin + (np.arange(th) + 0.5) / px_per_cm
    tile_i = np.floor(xs / 30.0).astype(int)
    tile_j = np.floor(ys / 30.0).astype(int)
    shades = rng.normal(0.0, 6.0, (tile_j.max() - tile_j.min() + 1, tile_i.max() - tile_i.min() + 1))
    tex = np.empty((th, tw, 3), np.float32)
    base = np.array([150.0, 162.0, 172.0], np.float32)
    shade = shades[(tile_j - tile_j.min())[:, None], (tile_i - tile_i.min())[None, :]]
    tex[...] = base + shade[..., None]
    tex += rng.normal(0.0, 4.0, (th, tw, 1)).astype(np.float32)
    grout_x = np.abs(((xs + 15.0) % 30.0) - 15.0) > 14.4
    grout_y = np.abs(((ys + 15.0) % 30.0) - 15.0) > 14.4
    tex[grout_y, :] = (110, 115, 118)
    tex[:, grout_x] = (110, 115, 118)
    # Tape outline of the working area (2.5 cm wide, neutral grey-white).
    for x_line in (0.0, 391.5):
        cols = np.abs(xs - x_line) < 1.25
        tex[np.ix_((ys > -1.25) & (ys < 550.75), cols)] = (210, 212, 214)
    for y_line in (0.0, 549.5):
        rows = np.abs(ys - y_line) < 1.25
        tex[np.ix_(rows, (xs > -1.25) & (xs < 392.75))] = (210, 212, 214)
    tex8 = np.clip(tex, 0, 255).astype(np.uint8)
    # Each image pixel looks up the floor point its ray meets (handles lens distortion).
    w, h = camera.width_px, camera.height_px
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = camera.pixel_to_plane(np.column_stack([uu.ravel(), vv.ravel()]), 0.0)
    map_x = ((xy[:, 0] - xmin) * px_per_cm - 0.5).reshape(h, w).astype(np.float32)
    map_y = ((xy[:, 1] - ymin) * px_per_cm - 0.5).reshape(h, w).astype(np.float32)
    return cv2.remap(tex8, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def frame(image: U8, index: int, fps: float = 30.0) -> Frame:
    return Frame(image=image, index=index, t_capture_s=1_700_000_000.0 + index / fps, t_mono_s=index / fps)


def three_rovers() -> list[SynthRover]:
    return [
        SynthRover("red", 100.0, 120.0, 0.3, COLORS["red"]),
        SynthRover("green", 250.0, 300.0, 1.2, COLORS["green"]),
        SynthRover("blue", 180.0, 500.0, -0.5, COLORS["blue"]),
    ]


_SCENES: dict[int, Scene] = {}


def shared_scene(seed: int = 0) -> Scene:
    """One scene per seed for the whole test session (building the floor takes about a second)."""
    if seed not in _SCENES:
        _SCENES[seed] = Scene(seed=seed)
    return _SCENES[seed]


def hue_colors(n: int, saturation: float = 0.75, value: float = 200.0) -> list[tuple[int, int, int]]:
    """``n`` marker colours evenly spaced in hue (for crowds), as BGR."""
    out = []
    for k in range(n):
        hsv = np.uint8([[[int(180 * k / n), int(255 * saturation), int(value)]]])
        b, g, r = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]
        out.append((int(b), int(g), int(r)))
    return out
