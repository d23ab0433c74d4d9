"""The renderer: a world state in, a camera frame out, with every configured camera and scene effect.

Design for speed (a 1280x720 frame with three rovers in a few milliseconds on one core):

* the static floor is rendered once (:mod:`edge.sim.backdrop`) and kept as a 16-bit tone-curve image with headroom
  above sensor white; each frame only the regions that change are redrawn into a working copy (rovers, people, the
  sunlit patch) and restored afterwards;
* rovers are drawn in small windows with *exact* area coverage of their projected faces (:mod:`edge.sim.raster`):
  the marker is where the camera model puts it to well under 0.05 px, with no supersampling;
* global light changes (illumination drift, auto-exposure, rolling flicker) are one gain stage over the whole frame
  (``cv2.convertScaleAbs``, then a per-row gain image for flicker);
* sensor noise comes from a precomputed bank read at a random offset, scaled by a per-value sigma table;
* JPEG only when the scenario asks for it.

Linear light (1.0 = sensor white at the nominal exposure) is what surfaces reflect; compositing happens in linear
light inside each window, so partly covered pixels mix light as a real pixel does. The camera's own processing of
that light is :mod:`edge.sim.sensor`; the shapes drawn (rectangles, boxes, marker parts) are :mod:`edge.sim.shapes`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera
from edge.errors import SimulationError
from edge.sim.backdrop import Backdrop, encode_linear, prerender
from edge.sim.colour import tone_encode
from edge.sim.effects import Effects, Occluder, Prop, at_row_times, drift_factor, sun_state
from edge.sim.raster import coverage, polygon_area
from edge.sim.scene import RoverLook, Scene, aruco_cells, rectangle_cm
from edge.sim.sensor import HEADROOM, CameraProcessing, exposure_blur
from edge.sim.shapes import (
    Box,
    Window,
    area_cm,
    box_faces,
    changing_region,
    fill,
    local,
    marker_parts,
    person_boxes,
    prop_box,
    subdivide,
    sun_shadow,
    window_around,
)
from edge.sim.world import RoverState, WorldState

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]
Image = NDArray[np.uint8]

SHADOW_STRENGTH = 0.55  # ambient occlusion under and around a rover's body
SHADOW_MARGIN_CM = 3.0
SHADOW_SIGMA_CM = 2.0
SIDE_LIGHT = 0.5  # vertical faces receive about half the irradiance of horizontal ones under ceiling lamps


@dataclass
class _Drawn:
    """A drawn marker, kept until the frame is done to account for nearer objects drawn over it."""

    rover_id: str
    window: Window
    marker: FloatArray  # remaining visible coverage of the marker in the window
    full_area_px: float


class Renderer:
    """Renders world states seen by ``camera`` in ``scene`` with ``effects``; deterministic for ``seed``.

    ``render(state, frame_index)`` returns a new (H, W, 3) uint8 BGR frame. Effects that depend on time (drift,
    flicker, clouds, people, auto-exposure) use ``t = frame_index / fps``; noise depends on ``(seed, frame_index)``.
    After each frame, ``visibility`` maps rover id -> fraction (0..1) of its marker's area visible in the frame
    (outside the image or hidden by nearer rovers or people counts as not visible).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        scene: Scene,
        effects: Effects,
        *,
        seed: int = 0,
        fps: float = 30.0,
        supersample: int = 2,
    ) -> None:
        if fps <= 0:
            raise SimulationError(f"renderer: fps must be positive, got {fps}")
        self.camera = camera
        self.scene = scene
        self.effects = effects
        self.seed = seed
        self.fps = fps
        self.height_px, self.width_px = camera.height_px, camera.width_px
        self._looks = {look.rover_id: look for look in scene.rovers}
        self._gamma = effects.exposure.gamma
        self._backdrop: Backdrop = prerender(camera, scene, effects, supersample)
        # The camera's fixed colour response (crosstalk, white balance) acts on linear light: the static room once,
        # everything drawn per frame in its window. Automatic white balance and the tone curve come last.
        self._sensor = CameraProcessing(effects, self._backdrop, (self.height_px, self.width_px), seed, fps)
        self._room = self._sensor.room
        self._bg = encode_linear(self._room, self._gamma, HEADROOM)
        self._work = self._bg.copy()
        self._decode = ((np.arange(65536, dtype=np.float64) / 65535.0) ** self._gamma * HEADROOM).astype(np.float32)
        self._encode = encode_linear(np.linspace(0.0, HEADROOM, 65536, dtype=np.float32), self._gamma, HEADROOM)
        self._full = Window(0, 0, self.width_px, self.height_px)
        self._sun_window = changing_region(self._backdrop.sun, self._backdrop.glare)
        self._aruco = {look.rover_id: aruco_cells(look) for look in scene.rovers if look.heading == "aruco"}
        self._subdivide = 6 if camera.has_distortion else 1
        self._size = (self.width_px, self.height_px)
        self.visibility: dict[str, float] = {}
        self._dirty: list[Window] = []

    # -- public ---------------------------------------------------------------------------------------------------
    def render(self, state: WorldState, frame_index: int) -> Image:
        """The camera frame of ``state`` captured as frame number ``frame_index``."""
        if frame_index < 0:
            raise SimulationError(f"renderer: frame index must not be negative, got {frame_index}")
        t_s = frame_index / self.fps
        rovers = state.rovers
        if self.effects.rolling_shutter is not None and rovers:  # each rover where it is when its row is exposed
            at = [(r.x_cm, r.y_cm, self._look(r.rover_id).body_height_cm) for r in rovers]
            rows = [float(v) for v in self.camera.project(np.array(at, float).reshape(-1, 3))[:, 1]]
            rovers = at_row_times(rovers, rows, self.effects.rolling_shutter.line_time_s)
        frame = self._compose(rovers, t_s)
        return self._capture(frame, frame_index, t_s)

    def background(self, frame_index: int = 0) -> Image:
        """The empty scene (no rovers, no people; the props already put down) as the camera captures it at
        ``frame_index``."""
        t_s = frame_index / self.fps
        frame = self._compose((), t_s, people=False)
        return self._capture(frame, frame_index, t_s, noise_stream=1)  # a capture of its own, not frame i's noise

    def marker_outline_px(self, rover: RoverState) -> FloatArray:
        """(N, 2) the rover's marker outline in distorted pixels (edges subdivided when the lens distorts)."""
        look = self._look(rover.rover_id)
        corners = rectangle_cm(rover.x_cm, rover.y_cm, rover.theta_rad, look.marker_length_cm, look.marker_width_cm)
        return self._project_outline(corners, look.body_height_cm, 32 if self.camera.has_distortion else 1)

    def nominal_marker_bgr(self, rover_id: str) -> tuple[int, int, int]:
        """The marker's colour as the camera sees it in the middle of the working area under the nominal light."""
        look = self._look(rover_id)
        return self.nominal_bgr(look.marker_bgr, look.body_height_cm)

    def nominal_bgr(self, albedo_bgr: tuple[float, float, float], z_cm: float) -> tuple[int, int, int]:
        """A horizontal surface of ``albedo_bgr`` at height ``z_cm`` in the middle of the working area as the camera
        sees it under the nominal light (its colour response and first frame's white balance included)."""
        centre = self.camera.project(np.array([[195.75, 274.75, z_cm]]))[0]
        u = int(np.clip(round(centre[0]), 0, self.width_px - 1))
        v = int(np.clip(round(centre[1]), 0, self.height_px - 1))
        lin = np.asarray(albedo_bgr, dtype=np.float32) * float(self._backdrop.illumination[v, u])
        lin = self._sensor.to_camera(lin.reshape(1, 1, 3)).reshape(3) * self._sensor.white_balance(0)
        enc = tone_encode(lin, self.effects.colour.tone, self._gamma) * 255.0
        b, g, r = (round(float(c)) for c in enc)
        return b, g, r

    # -- composition ----------------------------------------------------------------------------------------------
    def _compose(self, rovers: tuple[RoverState, ...], t_s: float, people: bool = True) -> NDArray[np.uint16]:
        work = self._work
        dirty: list[Window] = []
        drift = drift_factor(self.effects.drift, t_s)
        sun_strength, sun_colour = sun_state(self.effects.sun, t_s)
        sun_rel = sun_strength / drift  # the whole frame is multiplied by the drift later
        sun_rgb = (sun_rel * sun_colour).astype(np.float32)
        if self._sun_window is not None and sun_rel > 0:
            win = self._sun_window
            sl = win.slices
            lin = self._room[sl] + self._sun_floor(sl, sun_rgb, sun_rel)
            work[sl] = self._encode_fast(lin)
            dirty.append(win)
        # Far to near, so nearer objects cover farther ones.
        items: list[tuple[float, RoverState | Occluder | Prop]] = []
        cam = self.camera.position_cm
        for r in rovers:
            items.append((math.hypot(r.x_cm - cam[0], r.y_cm - cam[1]), r))
        if people:
            for person in self.effects.occluders:
                pose = person.pose(t_s)
                if pose is not None:
                    items.append((math.hypot(pose[0] - cam[0], pose[1] - cam[1]), person))
        for prop in self.effects.props:
            if prop.appears_s <= t_s:
                items.append((math.hypot(prop.x_cm - cam[0], prop.y_cm - cam[1]), prop))
        items.sort(key=lambda item: -item[0])
        drawn: list[_Drawn] = []
        self.visibility = {r.rover_id: 0.0 for r in rovers}
        for _, item in items:
            if isinstance(item, RoverState):
                result = self._draw_rover(work, item, sun_rgb, sun_rel)
            elif isinstance(item, Prop):
                result = self._draw_boxes(work, [prop_box(item)], sun_rgb=sun_rgb if sun_rel > 0 else None)
            else:
                result = self._draw_person(work, item, t_s, sun_rgb if sun_rel > 0 else None)
            if result is None:
                continue
            window, alpha, marker, marker_area = result
            dirty.append(window)
            for earlier in drawn:  # what this object covers of markers drawn before it is hidden
                overlap = earlier.window.intersect(window)
                if overlap is not None:
                    a = alpha[local(overlap, window)]
                    earlier.marker[local(overlap, earlier.window)] *= 1.0 - a
            if marker is not None and isinstance(item, RoverState):
                drawn.append(_Drawn(item.rover_id, window, marker, marker_area))
        for d in drawn:
            self.visibility[d.rover_id] = float(min(1.0, d.marker.sum() / max(d.full_area_px, 1e-9)))
        self._dirty = dirty
        return work

    def _capture(self, work: NDArray[np.uint16], frame_index: int, t_s: float, noise_stream: int = 0) -> Image:
        """The camera's processing of the composed frame (``edge.sim.sensor``); the working image is then restored
        where this frame drew."""
        frame = self._sensor.capture(work, frame_index, t_s, noise_stream)
        for win in self._dirty:
            sl = win.slices
            work[sl] = self._bg[sl]
        self._dirty = []
        return frame

    def _encode_fast(self, lin: F32) -> NDArray[np.uint16]:
        """Linear light to the 16-bit working code through a 65536-entry table (np.power is slow per pixel)."""
        lin *= np.float32(65535.0 / HEADROOM)
        np.clip(lin, 0.0, 65535.0, out=lin)
        return np.asarray(self._encode[lin.astype(np.uint16)])

    # -- rovers ---------------------------------------------------------------------------------------------------
    def _look(self, rover_id: str) -> RoverLook:
        look = self._looks.get(rover_id)
        if look is None:
            raise SimulationError(f"renderer: rover {rover_id!r} is not in the scene ({', '.join(self._looks)})")
        return look

    def _project_outline(self, corners_xy: FloatArray, z_cm: float, pieces: int) -> FloatArray:
        pts = subdivide(np.column_stack([corners_xy, np.full(len(corners_xy), z_cm)]), pieces)
        return self.camera.project(pts)

    def _draw_rover(
        self, work: NDArray[np.uint16], rover: RoverState, sun_rgb: F32, sun_rel: float
    ) -> tuple[Window, FloatArray, FloatArray | None, float] | None:
        """Draw one rover into the working image; (window, alpha, marker coverage, marker area px) or None."""
        look = self._look(rover.rover_id)
        x, y, th = rover.x_cm, rover.y_cm, rover.theta_rad
        hb = look.body_height_cm
        body = rectangle_cm(x, y, th, look.body_length_cm, look.body_width_cm)
        if not np.all(self.camera.in_front(np.column_stack([body, np.full(4, hb)]))):
            return None
        # The body's silhouette (the visible faces of a convex box tile the hull of its projected corners), its top
        # face and the marker parts; their coverage is computed exactly. Sides are lit at SIDE_LIGHT of the top.
        body_albedo = np.asarray(look.body_bgr)
        bottom_top = [np.column_stack([body, np.zeros(4)]), np.column_stack([body, np.full(4, hb)])]
        quads: list[FloatArray] = [bottom_top[1]]
        # Per output group (polygons in one group are disjoint and share a colour, like a tag's black cells):
        # premultiplied albedo (3), alpha, marker coverage. Group 0 is the silhouette, 1 the top face.
        weights: list[FloatArray] = [
            np.array([*(body_albedo * SIDE_LIGHT), 1.0, 0.0]),
            np.array([*(body_albedo * (1.0 - SIDE_LIGHT)), 0.0, 0.0]),
        ]
        groups = [0, 1]
        marker_index = 2
        shared_group = -1
        for m, (part, albedo, shared) in enumerate(marker_parts(look, x, y, th, self._aruco.get(look.rover_id))):
            # Part 0 is the whole marker over the body's top; later parts are albedo changes within it.
            quads.append(np.column_stack([part, np.full(4, hb)]))
            if shared and shared_group >= 0:
                groups.append(shared_group)
                continue
            groups.append(len(weights))
            shared_group = len(weights) if shared else shared_group
            change = albedo - body_albedo if m == 0 else albedo
            weights.append(np.array([*change, 0.0, 1.0 if m == 0 else 0.0]))
        sun = self.effects.sun if sun_rel > 0 else None
        if sun is not None:
            quads.append(np.column_stack([sun.patch_cm(hb), np.full(4, hb)]))
            groups.append(len(weights))
            weights.append(np.zeros(5))  # used for the lighting below, not drawn
        shadow_cm = rectangle_cm(
            x, y, th, look.body_length_cm + 2 * SHADOW_MARGIN_CM, look.body_width_cm + 2 * SHADOW_MARGIN_CM
        )
        verticals = [np.array([[*c, 0.0], [*c, hb]]) for c in body] if self.camera.has_distortion else []
        *projected, shadow_px = self._project_many(
            [*bottom_top, *quads[1:], *verticals, np.column_stack([shadow_cm, np.zeros(4)])]
        )
        outline = np.vstack([projected[0], projected[1], *projected[2 + len(quads) - 1 :]])
        silhouette = cv2.convexHull(outline.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        polys = [silhouette, projected[1], *projected[2 : 2 + len(quads) - 1]]

        # Windows: the body's (exact coverage) inside the shadow's (blurred, so a fixed-point fill is enough).
        kernel, psf_sigma = exposure_blur(self.effects, self.camera, rover, hb)
        blur_half = kernel.shape[0] // 2 if kernel is not None else math.ceil(3.0 * psf_sigma)
        sigma_px = max(SHADOW_SIGMA_CM * math.sqrt(abs(polygon_area(shadow_px)) / area_cm(shadow_cm)), 0.5)
        n_drawn = len(polys) - (1 if sun is not None else 0)
        body_window = window_around(np.vstack(polys[:n_drawn]), blur_half + 1, self._size)
        shadow_margin = math.ceil(2.0 * sigma_px) + blur_half
        window = window_around(np.vstack([*polys[:n_drawn], shadow_px]), shadow_margin, self._size)
        if body_window is None or window is None:
            return None
        h, w = window.height, window.width
        layer = np.zeros((h, w, 7), dtype=np.float32)  # premultiplied colour (3), alpha, marker, shadow, sun shadow
        cov = coverage(polys, (body_window.x0, body_window.y0), (body_window.height, body_window.width), groups)
        inner = local(body_window, window)
        wmat = np.asarray(weights)
        layer[inner][..., :5] = (cov.reshape(len(weights), -1).T @ wmat).reshape(
            body_window.height, body_window.width, 5
        )
        sl = window.slices
        light = self._backdrop.illumination[sl][..., None]
        if sun is not None:
            lit = np.zeros((h, w), dtype=np.float32)
            lit[inner] = cov[-1]
            vig = self._backdrop.vignetting[sl] * np.float32(self.effects.exposure.scale)
            light = np.asarray(light + (lit * vig)[..., None] * sun_rgb, dtype=np.float32)
        layer[..., :3] *= light
        if self._sensor.has_colour_response:
            layer[..., :3] = self._sensor.to_camera(layer[..., :3])
        layer[..., 5] = fill(shadow_px, window) * np.float32(SHADOW_STRENGTH)
        layer[..., 5] = cv2.GaussianBlur(layer[..., 5], (0, 0), sigma_px)
        if sun is not None:
            hull = sun_shadow(body, hb, sun.travel)
            (hull_px,) = self._project_many([np.column_stack([hull, np.zeros(len(hull))])])
            layer[..., 6] = fill(hull_px, window)
        # Visibility is geometric (the marker's area at mid-exposure), so keep alpha and marker before any blur.
        sharp_alpha, sharp_marker = layer[..., 3].astype(np.float64), layer[..., 4].astype(np.float64)
        if kernel is not None:
            layer = np.asarray(cv2.filter2D(layer, -1, kernel, borderType=cv2.BORDER_CONSTANT), dtype=np.float32)
        elif psf_sigma > 0.05:
            layer = np.asarray(
                cv2.GaussianBlur(layer, (0, 0), psf_sigma, borderType=cv2.BORDER_CONSTANT), dtype=np.float32
            )
        alpha = np.clip(layer[..., 3], 0.0, 1.0)
        seen = 1.0 - alpha  # how much of the floor shows through
        floor = self._decode[work[sl]]
        if sun is not None:
            sun_floor = self._sun_floor(sl, sun_rgb, sun_rel)
            floor -= sun_floor
            floor *= ((1.0 - layer[..., 5]) * seen)[..., None]
            floor += sun_floor * ((1.0 - layer[..., 6]) * seen)[..., None]
        else:
            floor *= ((1.0 - layer[..., 5]) * seen)[..., None]
        floor += layer[..., :3]
        work[sl] = self._encode_fast(floor)
        marker_area = abs(polygon_area(polys[marker_index]))
        return window, np.clip(sharp_alpha, 0.0, 1.0), sharp_marker, marker_area

    def _project_many(self, quads: list[FloatArray]) -> list[FloatArray]:
        """Project several world polygons in one call (edges subdivided when the lens distorts)."""
        pts = [subdivide(q, self._subdivide) for q in quads]
        uv = self.camera.project(np.vstack(pts))
        out, start = [], 0
        for p in pts:
            out.append(uv[start : start + len(p)])
            start += len(p)
        return out

    # -- sun ------------------------------------------------------------------------------------------------------
    def _sun_floor(self, sl: tuple[slice, slice], sun_rgb: F32, sun_rel: float) -> F32:
        """Linear light the sun (and its glare) adds to the floor in a window."""
        b = self._backdrop
        add = np.zeros((sl[0].stop - sl[0].start, sl[1].stop - sl[1].start, 3), dtype=np.float32)
        if b.sun is not None:
            add += b.sun[sl] * sun_rgb
        if b.glare is not None and self.effects.glare is not None:
            strength = sun_rel / max(self.effects.sun.strength if self.effects.sun else 1.0, 1e-9)
            add += b.glare[sl][..., None] * np.asarray(self.effects.glare.bgr, dtype=np.float32) * strength
        return self._sensor.to_camera(add)

    # -- people and props -------------------------------------------------------------------------------------------
    def _draw_person(
        self, work: NDArray[np.uint16], person: Occluder, t_s: float, sun_rgb: F32 | None = None
    ) -> tuple[Window, FloatArray, None, float] | None:
        pose = person.pose(t_s)
        if pose is None:
            return None
        # A person walking is not in perfect focus, and moves: a little more blur than the lens's.
        return self._draw_boxes(work, person_boxes(person, *pose), extra_blur_px=0.3, sun_rgb=sun_rgb)

    def _draw_boxes(
        self,
        work: NDArray[np.uint16],
        boxes: list[Box],
        extra_blur_px: float = 0.0,
        sun_rgb: F32 | None = None,
    ) -> tuple[Window, FloatArray, None, float] | None:
        """Draw boxes (centre, size (l, w, h), heading, albedo) with their camera-facing faces lit by the lamps, and
        a top face in the sunlit patch by the sun too."""
        cam = self.camera.position_cm
        faces: list[tuple[float, FloatArray, FloatArray]] = []  # (depth, world quad, colour factor)
        for centre, size, heading, albedo in boxes:
            for quad, normal in box_faces(centre, size, heading):
                mid = quad.mean(axis=0)
                if np.dot(normal, cam - mid) <= 0:
                    continue
                light = np.full(3, 1.0 if normal[2] > 0.5 else SIDE_LIGHT)
                if normal[2] > 0.5 and sun_rgb is not None:
                    light = light * self._sun_boost(mid, sun_rgb)
                faces.append((float(np.linalg.norm(cam - mid)), quad, albedo * light))
        if not faces:
            return None
        faces.sort(key=lambda f: -f[0])
        polys = [self.camera.project(subdivide(q, self._subdivide)) for _, q, _ in faces]
        window = window_around(np.vstack(polys), 3, self._size)
        if window is None:
            return None
        label = np.zeros((window.height, window.width), dtype=np.uint8)
        for i, poly in enumerate(polys):
            pts = np.rint((poly - [window.x0, window.y0]) * 16).astype(np.int32)
            cv2.fillPoly(label, [pts], int(i + 1), lineType=cv2.LINE_8, shift=4)
        palette = np.vstack([np.zeros(3), np.array([f[2] for f in faces])])
        colour = palette[label]
        alpha = (label > 0).astype(np.float64)
        sigma = extra_blur_px + (self.effects.optics.blur_sigma_px if self.effects.optics is not None else 0.0)
        if sigma > 0.05:
            colour = np.asarray(cv2.GaussianBlur(colour * alpha[..., None], (0, 0), sigma), dtype=np.float64)
            alpha = np.asarray(cv2.GaussianBlur(alpha, (0, 0), sigma), dtype=np.float64)
        sl = window.slices
        illum = self._backdrop.illumination[sl].astype(np.float32)
        lit = self._sensor.to_camera((colour * illum[..., None]).astype(np.float32))
        floor = self._decode[work[sl]].astype(np.float64)
        out = floor * (1.0 - alpha)[..., None] + lit
        work[sl] = self._encode_fast(out.astype(np.float32))
        return window, alpha, None, 0.0

    def _sun_boost(self, point_cm: FloatArray, sun_rgb: F32) -> FloatArray:
        """(3,) how much brighter than under the lamps alone a horizontal surface at ``point_cm`` (world, z its
        height) is when it lies in the sunlit patch; ones outside it."""
        sun = self.effects.sun
        if sun is None:
            return np.ones(3)
        patch = sun.patch_cm(float(point_cm[2])).astype(np.float32)
        if cv2.pointPolygonTest(patch.reshape(-1, 1, 2), (float(point_cm[0]), float(point_cm[1])), False) < 0:
            return np.ones(3)
        uv = self.camera.project(point_cm.reshape(1, 3))[0]
        u = int(np.clip(round(uv[0]), 0, self.width_px - 1))
        v = int(np.clip(round(uv[1]), 0, self.height_px - 1))
        lamps = float(self._backdrop.illumination[v, u])
        sun_light = (
            np.asarray(sun_rgb, np.float64) * float(self._backdrop.vignetting[v, u]) * self.effects.exposure.scale
        )
        return np.asarray(1.0 + sun_light / max(lamps, 1e-6))
