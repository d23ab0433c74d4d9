"""The camera half of the closed loop: the world rendered as the webcam sees it, and the tracker `edge-ips start` runs.

:class:`CameraPath` turns a world state into what the edge measured in that frame (:class:`Sighting`); the tracker
is :class:`edge.pipeline.Pipeline` with the default settings, the rovers' colours picked from a picture the way an
installer picks them, and the simulated camera's exact calibration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from edge.calibration.exact import exact_calibration
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, PinholeCamera
from edge.sim.effects import Effects
from edge.sim.render import Renderer
from edge.sim.scene import Scene
from edge.sim.world import RoverState, WorldState
from edge.tracking import Frame, RoverEstimate, Tracker

Bgr = tuple[int, int, int]


@dataclass(frozen=True)
class Mark:
    """Where the tracker put a rover in the image (full-resolution pixels)."""

    rover_id: str
    u_px: float
    v_px: float


@dataclass(frozen=True)
class Sighting:
    """One frame: the rendered image and the estimates of the rovers of the run the tracker made of it."""

    image: NDArray[np.uint8]
    estimates: tuple[RoverEstimate, ...]
    marks: tuple[Mark, ...]


class CameraPath:
    """Renderer -> tracker. ``wall0_s``: the wall-clock time of simulated time 0, for the frames' capture stamps."""

    def __init__(self, renderer: Renderer, tracker: Tracker, rover_ids: Sequence[str], wall0_s: float) -> None:
        self.renderer = renderer
        self.tracker = tracker
        self._ids = frozenset(rover_ids)
        self.wall0_s = wall0_s

    @property
    def camera(self) -> PinholeCamera:
        return self.renderer.camera

    def capture(self, state: WorldState, index: int, t_s: float) -> Sighting:
        """Render frame ``index`` of ``state`` (taken at simulated ``t_s``) and track it."""
        image = self.renderer.render(state, index)
        frame = Frame(image=image, index=index, t_capture_s=self.wall0_s + t_s, t_mono_s=t_s)
        estimates = tuple(e for e in self.tracker.process(frame).estimates if e.rover_id in self._ids)
        marks = tuple(Mark(e.rover_id, float(e.uv_px[0]), float(e.uv_px[1])) for e in estimates)
        return Sighting(image, estimates, marks)


def build_tracker(camera: PinholeCamera, scene: Scene, effects: Effects, seed: int, fps: float) -> Tracker:
    """The tracker `edge-ips start` runs on the simulated camera: :class:`edge.pipeline.Pipeline` with the default
    settings, the rovers' measured colours and the camera's exact calibration."""
    from edge.pipeline import Pipeline
    from edge.tracker_config import RoverConfig, TrackerConfig

    colors = marker_colors(camera, scene, effects, seed, fps)
    rovers = tuple(
        RoverConfig(id=rid, color_bgr=main, front_color_bgr=front, front_fraction=scene.look(rid).front_fraction)
        for rid, (main, front) in colors.items()
    )
    return Pipeline(TrackerConfig(rovers=rovers), exact_calibration(camera))


def marker_colors(
    camera: PinholeCamera,
    scene: Scene,
    effects: Effects,
    seed: int,
    fps: float = 30.0,
    at_cm: tuple[float, float] = (AREA_WIDTH_CM / 2, AREA_LENGTH_CM / 2),
) -> dict[str, tuple[Bgr, Bgr | None]]:
    """Each rover's marker colour, and its front colour (two-tone), as the camera sees them: measured on a frame of
    the rovers standing at ``at_cm`` (the middle of the paper's area by default; the middle of the camera's view for
    one of several), the way an installer picks them from a live picture."""
    renderer = Renderer(camera, scene, effects, seed=seed + 7919, fps=fps)
    out: dict[str, tuple[Bgr, Bgr | None]] = {}
    for k, look in enumerate(scene.rovers):
        x, y = at_cm
        state = WorldState(0.0, (RoverState(look.rover_id, x, y, 0.0, 0.0, 0.0),))
        image = renderer.render(state, k)
        main = _sample(image, camera, [x - 0.25 * look.marker_length_cm * look.front_fraction, y], look.body_height_cm)
        front = None
        if look.heading == "two_tone":
            front_x = x + 0.5 * look.marker_length_cm * (1.0 - look.front_fraction)
            front = _sample(image, camera, [front_x, y], look.body_height_cm)
        out[look.rover_id] = (main, front)
    return out


def _sample(image: NDArray[np.uint8], camera: PinholeCamera, xy_cm: Sequence[float], z_cm: float) -> Bgr:
    u, v = camera.project(np.array([[xy_cm[0], xy_cm[1], z_cm]]))[0]
    ui, vi = round(float(u)), round(float(v))
    patch = image[vi - 1 : vi + 2, ui - 1 : ui + 2].reshape(-1, 3)
    b, g, r = (round(float(c)) for c in np.median(patch, axis=0))
    return b, g, r


def annotate(image: NDArray[np.uint8], marks: Sequence[Mark]) -> NDArray[np.uint8]:
    """The camera view with a cross and the id at each of the tracker's estimates (the run's video)."""
    import cv2

    out = image.copy()
    for m in marks:
        if not (math.isfinite(m.u_px) and math.isfinite(m.v_px)):
            continue
        u, v = round(m.u_px), round(m.v_px)
        cv2.drawMarker(out, (u, v), (255, 255, 255), cv2.MARKER_CROSS, 18, 2)
        cv2.putText(out, m.rover_id, (u + 10, v - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
    return out
