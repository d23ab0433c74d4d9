"""The shapes the renderer draws, in the world and in the image: image rectangles, polygons subdivided for a
distorting lens, a rover's marker parts, boxes for props and people, the sun's shadow of a body."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.sim.effects import Occluder, Prop
from edge.sim.raster import polygon_area
from edge.sim.scene import RoverLook, rectangle_cm

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]
Box = tuple[FloatArray, FloatArray, float, FloatArray]  # centre, size (length, width, height), heading, albedo

WHITE_BGR = np.array([0.80, 0.82, 0.82])
INK_BGR = np.array([0.04, 0.04, 0.045])


@dataclass(frozen=True)
class Window:
    """A rectangle of the image: top-left pixel ``(x0, y0)`` and size."""

    x0: int
    y0: int
    width: int
    height: int

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.y0, self.y0 + self.height), slice(self.x0, self.x0 + self.width)

    def intersect(self, other: Window) -> Window | None:
        x0, y0 = max(self.x0, other.x0), max(self.y0, other.y0)
        x1 = min(self.x0 + self.width, other.x0 + other.width)
        y1 = min(self.y0 + self.height, other.y0 + other.height)
        if x1 <= x0 or y1 <= y0:
            return None
        return Window(x0, y0, x1 - x0, y1 - y0)


def window_around(points_px: FloatArray, margin: int, size_wh: tuple[int, int]) -> Window | None:
    """The image rectangle holding ``points_px`` with ``margin`` pixels round them, clipped to an image of
    ``size_wh``; None when nothing of it is in the image."""
    lo = np.floor(points_px.min(axis=0)).astype(int) - margin
    hi = np.ceil(points_px.max(axis=0)).astype(int) + margin + 1
    x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    x1, y1 = min(int(hi[0]), size_wh[0]), min(int(hi[1]), size_wh[1])
    if x1 <= x0 or y1 <= y0:
        return None
    return Window(x0, y0, x1 - x0, y1 - y0)


def fill(poly_px: FloatArray, window: Window) -> F32:
    """Anti-aliased fixed-point fill (1/16 px vertices) of a polygon in a window, 0..1 float32."""
    canvas = np.zeros((window.height, window.width), dtype=np.uint8)
    pts = np.rint((poly_px - [window.x0, window.y0]) * 16.0).astype(np.int32)
    cv2.fillPoly(canvas, [pts], 255, lineType=cv2.LINE_AA, shift=4)
    return canvas.astype(np.float32) * np.float32(1.0 / 255.0)


def marker_parts(
    look: RoverLook, x: float, y: float, th: float, aruco: FloatArray | None = None
) -> list[tuple[FloatArray, FloatArray, bool]]:
    """The marker as (world corners (4, 2), albedo, shared) parts: the first is the whole marker with its albedo,
    the others albedo changes within it; ``shared`` parts (a tag's black cells, ``aruco``: ``aruco_cells(look)``)
    are disjoint and alike."""
    albedo = np.asarray(look.marker_bgr)
    whole = rectangle_cm(x, y, th, look.marker_length_cm, look.marker_width_cm)
    parts = [(whole, albedo, False)]
    if look.heading == "two_tone":
        front_len = look.front_fraction * look.marker_length_cm
        shift = 0.5 * (look.marker_length_cm - front_len)
        cx, cy = x + shift * math.cos(th), y + shift * math.sin(th)
        front = rectangle_cm(cx, cy, th, front_len, look.marker_width_cm)
        parts.append((front, np.asarray(look.secondary_bgr) - albedo, False))
    elif look.heading == "aruco":
        side = look.aruco_side_cm
        parts.append((rectangle_cm(x, y, th, side, side), WHITE_BGR - albedo, False))
        c, s = math.cos(th), math.sin(th)
        for cell in aruco if aruco is not None else ():
            world = np.column_stack([x + cell[:, 0] * c - cell[:, 1] * s, y + cell[:, 0] * s + cell[:, 1] * c])
            parts.append((world, INK_BGR - WHITE_BGR, True))
    return parts


def local(inner: Window, outer: Window) -> tuple[slice, slice]:
    return (
        slice(inner.y0 - outer.y0, inner.y0 - outer.y0 + inner.height),
        slice(inner.x0 - outer.x0, inner.x0 - outer.x0 + inner.width),
    )


def subdivide(points: FloatArray, k: int) -> FloatArray:
    """(N, D) closed polygon -> (N * k, D) with each edge split into ``k`` pieces (curved under lens distortion)."""
    if k <= 1:
        return points
    nxt = np.roll(points, -1, axis=0)
    f = (np.arange(k) / k)[None, :, None]
    return (points[:, None, :] * (1 - f) + nxt[:, None, :] * f).reshape(-1, points.shape[1])


def area_cm(poly: FloatArray) -> float:
    return abs(polygon_area(poly))


def sun_shadow(body: FloatArray, height_cm: float, travel: FloatArray) -> FloatArray:
    """(M, 2) the body's shadow on the floor cast by the sun: hull of its corners projected along ``travel``."""
    top = body + (-height_cm / travel[2]) * travel[:2]
    pts = np.vstack([body, top]).astype(np.float32)
    hull = cv2.convexHull(pts).reshape(-1, 2)
    return np.asarray(hull, dtype=np.float64)


def box_faces(centre: FloatArray, size: FloatArray, heading: float) -> list[tuple[FloatArray, FloatArray]]:
    """The six faces of a box (world quads and outward normals); ``size`` = (length, width, height)."""
    c, s = math.cos(heading), math.sin(heading)
    ex = np.array([c, s, 0.0]) * size[0] / 2
    ey = np.array([-s, c, 0.0]) * size[1] / 2
    ez = np.array([0.0, 0.0, 1.0]) * size[2] / 2
    faces = []
    for axis, (u, v) in ((ex, (ey, ez)), (ey, (ez, ex)), (ez, (ex, ey))):
        for sign in (1.0, -1.0):
            f = centre + sign * axis
            quad = np.array([f - u - v, f + u - v, f + u + v, f - u + v])
            faces.append((quad, sign * axis / np.linalg.norm(axis)))
    return faces


def prop_box(prop: Prop) -> Box:
    """A prop as one box (centre, size, heading, albedo) standing on the floor."""
    size = np.asarray(prop.size_cm, dtype=np.float64)
    return np.array([prop.x_cm, prop.y_cm, 0.5 * size[2]]), size, prop.heading_rad, np.asarray(prop.albedo_bgr)


def person_boxes(person: Occluder, x_cm: float, y_cm: float, heading: float, walked_cm: float) -> list[Box]:
    """A person as boxes (centre, size (l, w, h), heading, albedo): legs swinging with the distance walked."""
    h = person.height_cm
    c, s = math.cos(heading), math.sin(heading)
    fwd, left = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    base = np.array([x_cm, y_cm, 0.0])
    swing = 12.0 * math.sin(walked_cm / 35.0 * math.pi)
    leg_h, torso_h, head_h = 0.49 * h, 0.36 * h, 0.13 * h
    trousers = np.asarray(person.trousers_bgr)
    shirt = np.asarray(person.shirt_bgr)
    skin = np.asarray(person.skin_bgr)
    boxes = []
    for side, phase in ((1.0, 1.0), (-1.0, -1.0)):
        centre = base + left * side * 10.0 + fwd * swing * phase + np.array([0.0, 0.0, leg_h / 2])
        boxes.append((centre, np.array([15.0, 14.0, leg_h]), heading, trousers))
    boxes.append((base + np.array([0.0, 0.0, leg_h + torso_h / 2]), np.array([24.0, 42.0, torso_h]), heading, shirt))
    for side, phase in ((1.0, -1.0), (-1.0, 1.0)):
        centre = base + left * side * 26.0 + fwd * swing * 0.6 * phase + np.array([0.0, 0.0, leg_h + torso_h * 0.45])
        boxes.append((centre, np.array([10.0, 9.0, torso_h * 0.9]), heading, shirt))
    boxes.append(
        (base + np.array([0.0, 0.0, leg_h + torso_h + head_h / 2]), np.array([20.0, 17.0, head_h]), heading, skin)
    )
    return boxes


def changing_region(sun: F32 | None, glare: F32 | None) -> Window | None:
    """The image rectangle where the sunlit patch (``sun``: (h, w, 3) light it adds) or its glare (``glare``:
    (h, w)) ever lights the floor: redrawn each frame while the sun shines; None without either."""
    masks = []
    if sun is not None:
        masks.append(sun.max(axis=2) > 1e-4)
    if glare is not None:
        masks.append(glare > 1e-4)
    if not masks:
        return None
    mask = np.logical_or.reduce(masks)
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return None
    return Window(int(cols.min()), int(rows.min()), int(cols.max() - cols.min() + 1), int(rows.max() - rows.min() + 1))
