"""A built scenario (:class:`SimSetup`: camera, scene, effects, plans, frames) and the pieces the scenario builders
share (their random streams, the lab's light, extra rovers circling)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from edge.camera import (
    AREA_LENGTH_CM,
    AREA_WIDTH_CM,
    MARKER_HEIGHT_CM,
    PinholeCamera,
    paper_camera,
)
from edge.sim.effects import (
    AutoExposure,
    Effects,
    Exposure,
    Flicker,
)
from edge.sim.render import Renderer
from edge.sim.scene import RoverLook, Scene
from edge.sim.trajectories import (
    grid_circles,
)
from edge.sim.world import DriveModel, Plan, World
from edge.tracker_config import RoverConfig

FPS = 30.0
AREA = (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM)


@dataclass(frozen=True)
class SimSetup:
    """Everything one simulation run needs. ``plans`` holds one scripted plan per rover id, in scene order."""

    scenario: str
    seed: int
    camera: PinholeCamera
    scene: Scene
    effects: Effects
    plans: tuple[tuple[str, Plan], ...]
    frames: int
    fps: float = FPS
    drive: DriveModel = field(default_factory=DriveModel)
    camera_name: str = "nominal"

    @property
    def rover_ids(self) -> tuple[str, ...]:
        return tuple(look.rover_id for look in self.scene.rovers)

    @property
    def marker_height_cm(self) -> float:
        """Height of the markers' plane (the rovers' bodies are all this tall): where a calibration belongs."""
        return self.scene.rovers[0].body_height_cm if self.scene.rovers else MARKER_HEIGHT_CM

    def world(self) -> World:
        """A fresh world with every rover on its scripted plan."""
        return World(dict(self.plans), self.drive, seed=self.seed)

    def renderer(self) -> Renderer:
        return Renderer(self.camera, self.scene, self.effects, seed=self.seed, fps=self.fps)

    def rover_configs(self, renderer: Renderer | None = None) -> tuple[RoverConfig, ...]:
        """The tracker's view of the fleet: each id with its marker's colour as this camera sees it (nominal light)."""
        r = renderer or self.renderer()
        return tuple(
            RoverConfig(id=look.rover_id, color_bgr=r.nominal_marker_bgr(look.rover_id)) for look in self.scene.rovers
        )


def scenario_rng(name: str, seed: int) -> np.random.Generator:
    """The random stream of scenario ``name`` (or one of its parts) for ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([seed, sum(ord(c) * 131**i for i, c in enumerate(name))]))


def lab_effects(rng: np.random.Generator) -> Effects:
    """The paper's lab without its curtains drawn: fluorescent light, a webcam's auto-exposure at 1/60 s."""
    return Effects(
        exposure=Exposure(exposure_s=1.0 / 60.0),
        auto_exposure=AutoExposure(),
        flicker=Flicker(modulation=0.2, phase=float(rng.uniform(0, 2 * math.pi))),
    )


def make_setup(
    name: str,
    seed: int,
    frames: int,
    looks: tuple[RoverLook, ...],
    plans: list[Plan],
    effects: Effects,
    camera: PinholeCamera | None = None,
) -> SimSetup:
    pairs = tuple((look.rover_id, plan) for look, plan in zip(looks, plans, strict=True))
    return SimSetup(name, seed, camera or paper_camera(), Scene(looks), effects, pairs, frames)


def with_extras(
    designed: list[Plan], n: int, region: tuple[float, float, float, float], rng: np.random.Generator
) -> list[Plan]:
    """The first ``n`` designed plans; any rovers beyond them circle in cells of ``region``."""
    if n <= len(designed):
        return designed[:n]
    return designed + grid_circles(n - len(designed), region, rng)


def jitter(rng: np.random.Generator, cm: float) -> float:
    return float(rng.uniform(-cm, cm))


Run = tuple[tuple[float, float], float, float, float]  # (point cm, heading rad, delay s, run-up cm)
