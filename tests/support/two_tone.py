"""Helpers for the two-tone marker tests: the simulator's brightest floor, a rover spinning or driving across it,
and the tracker's errors on the rendered frames."""

from __future__ import annotations

import math
from collections.abc import Container, Iterator
from dataclasses import dataclass

import numpy as np

from edge.calibration.exact import exact_calibration
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.pipeline import Pipeline
from edge.sim.loop import marker_colors
from edge.sim.scenarios import SimSetup
from edge.sim.world import RoverState, WorldState
from edge.tracker_config import RoverConfig, TrackerConfig
from edge.tracking import Frame

FPS = 30.0
Pose = tuple[float, float, float]  # x cm, y cm, theta rad


def brightest_floor_cm(setup: SimSetup, frame_index: int = 0, margin_cm: float = 40.0) -> tuple[float, float]:
    """Where the empty floor looks brightest to the camera (a lamp's reflection, the sun's glare), inside the
    working area less ``margin_cm``: the point of the marker plane (13 cm) that the brightest pixel looks at, so a
    marker there sits on the reflection in the image."""
    camera = setup.camera
    image = setup.renderer().background(frame_index).astype(np.float32).mean(axis=2)
    h, w = image.shape
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    floor = camera.pixel_to_plane(np.column_stack([uu.ravel(), vv.ravel()]), 0.0).reshape(h, w, 2)
    inside = (
        (floor[..., 0] >= margin_cm)
        & (floor[..., 0] <= AREA_WIDTH_CM - margin_cm)
        & (floor[..., 1] >= margin_cm)
        & (floor[..., 1] <= AREA_LENGTH_CM - margin_cm)
    )
    blurred = np.where(inside, image, 0.0)
    v, u = np.unravel_index(int(np.argmax(blurred)), blurred.shape)
    x, y = camera.pixel_to_plane(np.array([[float(u), float(v)]]), 13.0)[0]
    return float(x), float(y)


def spinning(x: float, y: float, theta0: float, rate_rad_s: float, frames: int) -> Iterator[Pose]:
    """A rover turning in place at (x, y)."""
    for k in range(frames):
        yield x, y, theta0 + rate_rad_s * k / FPS


def crossing(x: float, y: float, theta: float, speed_cm_s: float, frames: int) -> Iterator[Pose]:
    """A rover driving straight through (x, y) at mid-run (backwards when ``speed_cm_s`` < 0), heading ``theta``."""
    for k in range(frames):
        s = speed_cm_s * (k - frames / 2) / FPS
        yield x + s * math.cos(theta), y + s * math.sin(theta), theta


def turning_unseen(x: float, y: float, theta0: float, turn_rad: float, gap: range, speed_cm_s: float) -> Iterator[Pose]:
    """A rover standing at (x, y) heading ``theta0`` that turns by ``turn_rad`` during the frames of ``gap`` and
    then drives straight on at ``speed_cm_s``; ``gap.stop + 90`` frames in all."""
    theta = theta0
    for k in range(gap.stop + 90):
        if k in gap:
            theta = theta0 + turn_rad * (k - gap.start + 1) / len(gap)
        elif k >= gap.stop:
            x += speed_cm_s / FPS * math.cos(theta)
            y += speed_cm_s / FPS * math.sin(theta)
        yield x, y, theta


def appearing(x: float, y: float, headings: int, shown: int = 8, hidden: int = 4) -> Iterator[Pose | None]:
    """A rover standing at (x, y) at ``headings`` evenly spaced headings in turn, each for ``shown`` frames, out of
    view (None) for ``hidden`` frames in between: the tracker loses it and must find its front from scratch."""
    for k in range(headings):
        for _ in range(shown):
            yield x, y, math.tau * k / headings
        for _ in range(hidden):
            yield None


@dataclass
class Errors:
    """Per frame in view: None (no pose), else (centre error cm, heading error deg or None when no heading
    reported)."""

    frames: list[tuple[float, float | None] | None]

    @property
    def detected(self) -> float:
        return sum(f is not None for f in self.frames) / len(self.frames)

    @property
    def centre_cm(self) -> list[float]:
        return [f[0] for f in self.frames if f is not None]

    @property
    def heading_deg(self) -> list[float]:
        return [f[1] for f in self.frames if f is not None and f[1] is not None]


def track_one(setup: SimSetup, path: Iterator[Pose | None], seed: int = 0, dropped: Container[int] = ()) -> Errors:
    """Render the setup's first rover (two-tone) along ``path`` (x, y, theta per frame, with the velocity that
    implies; None: out of view), track it with the pipeline as the loop builds it, and score every frame in view
    against the truth. Frames numbered in ``dropped`` never reach the tracker (a camera or a computer that fell
    behind dropped them) and are not scored."""
    rid = setup.scene.rovers[0].rover_id
    renderer = setup.renderer()
    main, front = marker_colors(setup.camera, setup.scene, setup.effects, seed)[rid]
    assert front is not None, "the setup's markers must be two-tone"
    config = TrackerConfig(rovers=(RoverConfig(id=rid, color_bgr=main, front_color_bgr=front),))
    tracker = Pipeline(config, exact_calibration(setup.camera))
    out: list[tuple[float, float | None] | None] = []
    last: tuple[float, float, float] | None = None
    for k, pose in enumerate(path):
        if pose is None:
            state = WorldState(k / FPS, ())
        else:
            x, y, theta = pose
            vx, vy = (0.0, 0.0) if last is None else ((x - last[0]) * FPS, (y - last[1]) * FPS)
            state = WorldState(k / FPS, (RoverState(rid, x, y, theta, vx, vy),))
        last = pose
        if k in dropped:
            continue
        image = renderer.render(state, k)
        result = tracker.process(Frame(image=image, index=k, t_capture_s=k / FPS, t_mono_s=k / FPS))
        if pose is None:
            continue
        if not result.estimates:
            out.append(None)
            continue
        (e,) = result.estimates
        heading = None
        if e.theta_rad is not None:
            heading = abs(math.degrees(math.remainder(e.theta_rad - theta, math.tau)))
        out.append((math.hypot(e.x_cm - x, e.y_cm - y), heading))
    return Errors(out)
