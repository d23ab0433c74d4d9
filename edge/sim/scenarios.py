"""Named scenarios: the paper's lab and the conditions it avoided (curtains, few rovers, an ideal lens).

A :class:`Scenario` is a name, one line of help and a builder; ``build(name, seed, rovers, frames)`` gives a
:class:`SimSetup`: the camera, the scene (with each rover's id and marker colour), the effects, each rover's plan,
the frame rate and the number of frames. The seed varies trajectories (phases, centres, speeds), lighting phases
and noise, so figures can be checked on unseen seeds.

| name      | what it exercises |
|-----------|-------------------|
| lab       | the paper's setup under fluorescent light: circle, stop-and-go and diagonal runs |
| drift     | room light drifting +-35 % and a lamp bank switched off, fixed exposure, strong rolling flicker |
| sun       | no curtains: a sunlit window patch changing with clouds, a glare on the floor, auto-exposure lag |
| cross     | rovers passing head-on and crossing paths with 1 cm between bodies, near and far |
| occlusion | a person walks in and stands in front of a rover; a rover leaves the view and comes back |
| lens      | a distorting lens (barrel, tangential, off-centre principal point) and MJPG compression |
| crowd     | twelve rovers (or ``--rovers N``; eight: the eight-hue palette) with distinct hues circling at once |
| daylight  | rovers crossing a strong warm sunlit patch and its glare, lamps switched off, automatic white balance, a
              grey and a white box put down in the area |

Every scenario can be seen through the nominal camera (``camera="nominal"``, the C920-like camera of the docs) or
through a camera of the family drawn from the seed (``camera="family"``, :mod:`edge.sim.cameras`: chroma sampling,
JPEG quality, blur, tone curve, crosstalk, white balance, noise, vignetting, the processor's demosaicing and
sharpening, and the rovers' body colours, height and margins).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

from edge.errors import SimulationError
from edge.sim.builders import (
    build_cross,
    build_crowd,
    build_daylight,
    build_drift,
    build_lab,
    build_lens,
    build_occlusion,
    build_sun,
    lens_camera,
)
from edge.sim.cameras import draw_family
from edge.sim.scene import FLOORS, HEADINGS, Heading
from edge.sim.setup import FPS, SimSetup, lab_effects

__all__ = ["FPS", "SCENARIOS", "Scenario", "SimSetup", "build", "get_scenario", "lab_effects", "lens_camera"]

Builder = Callable[[int, int, int], SimSetup]
CameraChoice = Literal["nominal", "family"]
CAMERAS: tuple[CameraChoice, ...] = ("nominal", "family")


@dataclass(frozen=True)
class Scenario:
    name: str
    summary: str
    default_rovers: int
    default_frames: int
    builder: Builder

    def build(
        self,
        seed: int = 0,
        rovers: int | None = None,
        frames: int | None = None,
        heading: Heading = "plain",
        camera: CameraChoice = "nominal",
        floor: str = "tiles",
    ) -> SimSetup:
        """The run for ``seed``; ``heading`` puts heading markers (two-tone or ArUco) on every rover; ``camera``:
        the nominal camera, or one of the family drawn from the seed (with bodies drawn from the family too);
        ``floor``: the floor's material (``edge.sim.scene.FLOORS``)."""
        n = self.default_rovers if rovers is None else rovers
        f = self.default_frames if frames is None else frames
        if n < 1:
            raise SimulationError(f"scenario {self.name}: --rovers must be at least 1, got {n}")
        if f < 1:
            raise SimulationError(f"scenario {self.name}: --frames must be at least 1, got {f}")
        if camera not in CAMERAS:
            raise SimulationError(f"scenario {self.name}: --camera must be one of {', '.join(CAMERAS)}")
        if heading not in HEADINGS:
            raise SimulationError(f"scenario {self.name}: --heading must be one of {', '.join(HEADINGS)}")
        if floor not in FLOORS:
            raise SimulationError(f"scenario {self.name}: --floor must be one of {', '.join(FLOORS)}")
        setup = self.builder(seed, n, f)
        looks = setup.scene.rovers
        if heading != "plain":
            looks = tuple(replace(look, heading=heading, aruco_id=k) for k, look in enumerate(looks))
        if camera == "family":
            drawn, looks = draw_family(self.name, seed, looks)
            setup = replace(setup, effects=drawn.apply(setup.effects), camera_name=drawn.name)
        return replace(setup, scene=replace(setup.scene, rovers=looks, floor=FLOORS[floor]))


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "lab", "the paper's lab: fluorescent light, a circle, a stop-and-go loop and a diagonal", 3, 450, build_lab
        ),
        Scenario(
            "drift",
            "light drifting +-35% and a lamp bank switched off, fixed exposure, rolling flicker",
            3,
            450,
            build_drift,
        ),
        Scenario(
            "sun",
            "no curtains: sunlit patch with passing clouds, floor glare, lamps switched, auto-exposure lag",
            3,
            450,
            build_sun,
        ),
        Scenario(
            "cross", "head-on passes and crossings with 1 cm between bodies, near and far side", 3, 840, build_cross
        ),
        Scenario(
            "occlusion",
            "a person stands in front of a rover for a while; a rover leaves the view and returns",
            3,
            450,
            build_occlusion,
        ),
        Scenario(
            "lens",
            "distorting lens with off-centre principal point and MJPG compression, diagonal runs",
            3,
            630,
            build_lens,
        ),
        Scenario(
            "crowd", "twelve rovers with distinct hues circling at once (--rovers up to 48)", 12, 300, build_crowd
        ),
        Scenario(
            "daylight",
            "strong warm sunlit patch and glare, lamps off, auto white balance, a grey and a white box put down",
            3,
            450,
            build_daylight,
        ),
    )
}


def get_scenario(name: str) -> Scenario:
    found = SCENARIOS.get(name)
    if found is None:
        raise SimulationError(f"unknown scenario {name!r}; choose one of: {', '.join(SCENARIOS)}")
    return found


def build(
    name: str,
    seed: int = 0,
    rovers: int | None = None,
    frames: int | None = None,
    heading: Heading = "plain",
    camera: CameraChoice = "nominal",
    floor: str = "tiles",
) -> SimSetup:
    """The :class:`SimSetup` of scenario ``name`` for ``seed`` (``rovers``/``frames`` default to the scenario's;
    ``heading``: ``plain``, ``two_tone`` or ``aruco`` markers; ``camera``: ``nominal`` or ``family``; ``floor``: a
    material of ``edge.sim.scene.FLOORS``)."""
    return get_scenario(name).build(seed, rovers, frames, heading, camera, floor)
