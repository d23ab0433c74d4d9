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
JPEG quality, blur, tone curve, crosstalk, white balance, noise, vignetting, and the rovers' body colours, height
and margins).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from edge.camera import (
    AREA_LENGTH_CM,
    AREA_WIDTH_CM,
    MARKER_HEIGHT_CM,
    PAPER_CAMERA_AIM_Y_CM,
    PAPER_CAMERA_HEIGHT_CM,
    PAPER_CAMERA_SETBACK_CM,
    PinholeCamera,
    paper_camera,
)
from edge.errors import SimulationError
from edge.sim.cameras import draw_bodies, draw_camera
from edge.sim.colour import AutoWhiteBalance
from edge.sim.effects import (
    AutoExposure,
    Compression,
    Effects,
    Exposure,
    Flicker,
    Glare,
    IlluminationDrift,
    Occluder,
    Prop,
    SunPatch,
    sun_mirror_point,
)
from edge.sim.render import Renderer
from edge.sim.scene import HEADINGS, Heading, RoverLook, Scene, fleet_looks
from edge.sim.trajectories import (
    circle,
    crossing_gap_s,
    diagonal,
    grid_circles,
    leave_and_return,
    stop_and_go,
    time_to_distance,
    transfer,
)
from edge.sim.world import DriveModel, Plan, Pose, Segment, Straight, Wait, World
from edge.tracker_config import RoverConfig

FPS = 30.0
AREA = (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM)
# C920-like lens at 1280x720, exaggerated a little so the lens scenario is a real test: barrel distortion (about
# 40 px at the corners), a little tangential distortion and a principal point off the image centre.
LENS_DIST_COEFFS = (-0.12, 0.06, 0.0012, -0.0009, 0.0)
LENS_PRINCIPAL_OFFSET_PX = (9.0, -6.0)


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
    ) -> SimSetup:
        """The run for ``seed``; ``heading`` puts heading markers (two-tone or ArUco) on every rover; ``camera``:
        the nominal camera, or one of the family drawn from the seed (with bodies drawn from the family too)."""
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
        setup = self.builder(seed, n, f)
        looks = setup.scene.rovers
        if heading != "plain":
            looks = tuple(replace(look, heading=heading, aruco_id=k) for k, look in enumerate(looks))
        if camera == "family":
            rng = _rng(f"{self.name}/camera", seed)
            drawn = draw_camera(rng)
            looks = draw_bodies(looks, rng)
            setup = replace(setup, effects=drawn.apply(setup.effects), camera_name=drawn.name)
        return replace(setup, scene=replace(setup.scene, rovers=looks))


# -- shared pieces ----------------------------------------------------------------------------------------------
def _rng(name: str, seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, sum(ord(c) * 131**i for i, c in enumerate(name))]))


def lab_effects(rng: np.random.Generator) -> Effects:
    """The paper's lab without its curtains drawn: fluorescent light, a webcam's auto-exposure at 1/60 s."""
    return Effects(
        exposure=Exposure(exposure_s=1.0 / 60.0),
        auto_exposure=AutoExposure(),
        flicker=Flicker(modulation=0.2, phase=float(rng.uniform(0, 2 * math.pi))),
    )


def _setup(
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


def _with_extras(
    designed: list[Plan], n: int, region: tuple[float, float, float, float], rng: np.random.Generator
) -> list[Plan]:
    """The first ``n`` designed plans; any rovers beyond them circle in cells of ``region``."""
    if n <= len(designed):
        return designed[:n]
    return designed + grid_circles(n - len(designed), region, rng)


def _jitter(rng: np.random.Generator, cm: float) -> float:
    return float(rng.uniform(-cm, cm))


Run = tuple[tuple[float, float], float, float, float]  # (point cm, heading rad, delay s, run-up cm)


# -- scenarios --------------------------------------------------------------------------------------------------
def _lab_plans(rng: np.random.Generator) -> list[Plan]:
    red = circle(
        (115.0 + _jitter(rng, 15), 165.0 + _jitter(rng, 15)),
        75.0 + _jitter(rng, 8),
        laps=1.75,
        speed_cm_s=20.0 + _jitter(rng, 3),
        start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
        ccw=bool(rng.random() < 0.5),
    )
    gx = 300.0 + _jitter(rng, 15)
    green = stop_and_go(
        Pose(gx, 80.0, math.pi / 2),
        [(gx + 20, 230.0 + _jitter(rng, 20)), (gx - 60, 330.0 + _jitter(rng, 20)), (gx, 80.0)],
        speed_cm_s=22.0,
        stop_s=1.0,
    )
    blue = diagonal(
        (40.0 + _jitter(rng, 10), 320.0 + _jitter(rng, 10)),
        (250.0 + _jitter(rng, 10), 530.0 + _jitter(rng, 10)),
        speed_cm_s=22.0,
        come_back=True,
    )
    return [red, green, blue]


def build_lab(seed: int, n: int, frames: int) -> SimSetup:
    rng = _rng("lab", seed)
    looks = fleet_looks(n)
    plans = _lab_plans(rng) if n <= 3 else grid_circles(n, AREA, rng)
    return _setup("lab", seed, frames, looks, plans[:n], lab_effects(rng))


def build_drift(seed: int, n: int, frames: int) -> SimSetup:
    rng = _rng("drift", seed)
    looks = fleet_looks(n)
    plans = _lab_plans(rng) if n <= 3 else grid_circles(n, AREA, rng)
    t_off = float(rng.uniform(3.0, 5.0))
    effects = Effects(
        exposure=Exposure(exposure_s=1.0 / 250.0),
        auto_exposure=None,  # fixed exposure, as an installer would set it: the drift reaches the image in full
        flicker=Flicker(modulation=0.25, phase=float(rng.uniform(0, 2 * math.pi))),
        drift=IlluminationDrift(
            amplitude=0.35,
            period_s=10.0,
            phase=float(rng.uniform(0, 2 * math.pi)),
            switches=((t_off, t_off + 3.0, 0.72),),
        ),
    )
    return _setup("drift", seed, frames, looks, plans[:n], effects)


def build_sun(seed: int, n: int, frames: int) -> SimSetup:
    """Red circles in the sunlit patch and through the glare; green drives in and out of the patch; blue stops and
    goes under the lamps of the near side while the auto-exposure reacts to the passing clouds and to half the lamps
    being switched off for 3 s."""
    rng = _rng("sun", seed)
    looks = fleet_looks(n)
    camera = paper_camera()
    sun = SunPatch(cloud_phase=float(rng.uniform(0, 1)))
    gx, gy = sun_mirror_point(camera.position_cm, sun)
    designed = [
        circle(
            (160.0 + _jitter(rng, 8), 280.0 + _jitter(rng, 10)),
            45.0,
            laps=3.0,
            speed_cm_s=18.0,
            start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
            ccw=bool(rng.random() < 0.5),
        ),
        diagonal((255.0, 110.0 + _jitter(rng, 15)), (255.0, 470.0 + _jitter(rng, 15)), speed_cm_s=22.0, come_back=True),
        stop_and_go(
            Pose(40.0, 95.0 + _jitter(rng, 10), 0.0),
            [(200.0, 105.0), (340.0, 90.0 + _jitter(rng, 10)), (40.0, 95.0)],
            speed_cm_s=22.0,
        ),
    ]
    t_off = float(rng.uniform(4.0, 6.0))
    effects = Effects(
        exposure=Exposure(exposure_s=1.0 / 60.0),
        auto_exposure=AutoExposure(),
        sun=sun,
        glare=Glare(x_cm=gx, y_cm=gy),
        # someone switches half the lamps off for 3 s: the auto-exposure under-exposes, then over-exposes, a few frames
        drift=IlluminationDrift(amplitude=0.0, switches=((t_off, t_off + 3.0, 0.6),)),
    )
    plans = _with_extras(designed, n, (0.0, 360.0, 210.0, AREA_LENGTH_CM), rng)
    return _setup("sun", seed, frames, looks, plans, effects, camera=camera)


def build_cross(seed: int, n: int, frames: int) -> SimSetup:
    """Red and green pass head-on in adjacent lanes (1 cm between bodies); blue crosses a lane right behind them.

    Twice: in the near half of the area, then at its far side (markers ~20 x 9 px).
    """
    rng = _rng("cross", seed)
    looks = fleet_looks(n)
    look = looks[0]
    v = 20.0
    lane = look.body_width_cm + 1.0  # centre to centre: the bodies pass 1 cm apart
    gap = crossing_gap_s(look.body_length_cm, look.body_width_cm, look.body_length_cm, look.body_width_cm, v, 1.0)
    events = [
        ((195.0 + _jitter(rng, 20), 200.0 + _jitter(rng, 20)), float(rng.uniform(-0.3, 0.3))),
        ((195.0 + _jitter(rng, 20), 500.0 + _jitter(rng, 10)), float(rng.uniform(-0.3, 0.3))),
    ]
    runs: list[list[Run]] = []
    for k, (point, heading) in enumerate(events):
        c, s = math.cos(heading), math.sin(heading)
        red_pt = (point[0] - s * lane / 2, point[1] + c * lane / 2)
        green_pt = (point[0] + s * lane / 2, point[1] - c * lane / 2)
        # Directions alternate between events so each rover's next run starts on the side where its last one ended
        # (nobody cuts across anybody between events). Blue crosses the outer lane's rover right behind it, coming
        # from outside the lanes: first red's lane from beyond it, then green's from below it.
        red_dir = heading if k % 2 == 0 else heading + math.pi
        blue = (
            (red_pt, heading - math.pi / 2, gap, 60.0) if k % 2 == 0 else (green_pt, heading + math.pi / 2, gap, 60.0)
        )
        runs.append([(red_pt, red_dir, 0.0, 70.0), (green_pt, red_dir + math.pi, 0.0, 70.0), blue])
    plans = _choreography(runs, first_time_s=3.5 + float(rng.uniform(0, 0.5)), speed_cm_s=v)
    plans = _with_extras(plans, n, (0.0, 260.0, 90.0, 440.0), rng)
    return _setup("cross", seed, frames, looks, plans, lab_effects(rng))


def _choreography(events: list[list[Run]], first_time_s: float, speed_cm_s: float) -> list[Plan]:
    """One plan per rover through a sequence of timed passes.

    ``events[e][r]`` is rover ``r``'s :data:`Run` in event ``e``: it passes ``point`` heading ``heading`` at the
    event's time plus ``delay_s``, on a straight run starting ``run_up_cm`` before the point. Between events each
    rover drives to its next run's start; each event is scheduled as soon as every rover can make it.
    """
    n = len(events[0])
    segments: list[list[Segment]] = [[] for _ in range(n)]
    starts: list[Pose] = []
    ends: list[Pose] = []
    t_event = first_time_s
    for e, runs in enumerate(events):
        run_starts = [Pose(p[0] - run_up * math.cos(h), p[1] - run_up * math.sin(h), h) for p, h, _, run_up in runs]
        lead = [time_to_distance(run_up, speed_cm_s) for _, _, _, run_up in runs]
        if e == 0:
            starts = run_starts
            legs: list[list[Segment]] = [[] for _ in range(n)]
            ready = [0.0] * n
        else:
            legs = [transfer(ends[r], run_starts[r]) for r in range(n)]
            ready = [Plan(starts[r], segments[r] + legs[r]).duration_s for r in range(n)]
        t_event = max([t_event] + [ready[r] + lead[r] - runs[r][2] + 0.5 for r in range(n)])
        for r, (_, _, delay, run_up) in enumerate(runs):
            segments[r] += [*legs[r], Wait(t_event + delay - lead[r] - ready[r]), Straight(2 * run_up, speed_cm_s)]
        ends = [Pose(p[0] + run_up * math.cos(h), p[1] + run_up * math.sin(h), h) for p, h, _, run_up in runs]
    return [Plan(starts[r], [*segments[r], Wait(1.0)]) for r in range(n)]


def build_occlusion(seed: int, n: int, frames: int) -> SimSetup:
    """A person walks in, stands between the camera and the red rover for ~3 s and leaves; blue drives out of the
    view through its near edge, waits and comes back."""
    rng = _rng("occlusion", seed)
    looks = fleet_looks(n)
    stand = (175.0 + _jitter(rng, 15), 230.0 + _jitter(rng, 15))
    t_in = 2.0 + float(rng.uniform(0, 1))
    person = Occluder(
        keyframes=(
            (t_in, -260.0, stand[1] - 40.0),
            (t_in + 3.5, stand[0], stand[1]),
            (t_in + 6.5, stand[0], stand[1]),
            (t_in + 10.0, 650.0, stand[1] + 60.0),
        )
    )
    red = circle(
        (stand[0] + 10.0, stand[1] + 160.0),
        55.0,
        laps=2.5,
        speed_cm_s=18.0,
        start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
    )
    blue_start = Pose(300.0 + _jitter(rng, 15), 70.0 + _jitter(rng, 10), -math.pi / 2)
    blue = leave_and_return(blue_start, (blue_start.x_cm + 10.0, -75.0), speed_cm_s=30.0, away_s=1.5)
    green = stop_and_go(Pose(60.0, 420.0, 0.0), [(120.0, 500.0), (60.0, 420.0)], speed_cm_s=18.0, stop_s=1.5)
    plans = _with_extras([red, green, blue], n, (0.0, 0.0, 110.0, 350.0), rng)
    effects = lab_effects(rng)
    effects = Effects(
        exposure=effects.exposure, auto_exposure=effects.auto_exposure, flicker=effects.flicker, occluders=(person,)
    )
    return _setup("occlusion", seed, frames, looks, plans, effects)


def lens_camera() -> PinholeCamera:
    return PinholeCamera.look_at(
        (AREA_WIDTH_CM / 2.0, -PAPER_CAMERA_SETBACK_CM, PAPER_CAMERA_HEIGHT_CM),
        (AREA_WIDTH_CM / 2.0, PAPER_CAMERA_AIM_Y_CM, 0.0),
        width_px=1280,
        height_px=720,
        hfov_deg=70.0,
        dist_coeffs=LENS_DIST_COEFFS,
        principal_offset_px=LENS_PRINCIPAL_OFFSET_PX,
    )


def build_lens(seed: int, n: int, frames: int) -> SimSetup:
    """The paper's diagonal run (Fig. 37) in three parallel lanes, through a distorting lens, MJPG-compressed."""
    rng = _rng("lens", seed)
    looks = fleet_looks(n)
    direction = np.array([AREA_WIDTH_CM, AREA_LENGTH_CM]) / math.hypot(AREA_WIDTH_CM, AREA_LENGTH_CM)
    across = np.array([-direction[1], direction[0]])
    designed = []
    for k in (-1, 0, 1):
        start = np.array([22.0, 22.0]) + k * 34.0 * across + direction * float(rng.uniform(0, 10))
        end = start + direction * (math.hypot(AREA_WIDTH_CM, AREA_LENGTH_CM) - 50.0)
        designed.append(
            diagonal(
                (float(start[0]), float(start[1])),
                (float(end[0]), float(end[1])),
                speed_cm_s=30.0,
                wait_before_s=float(rng.uniform(0.5, 1.5)),
            )
        )
    order = [designed[1], designed[0], designed[2]]
    plans = _with_extras(order, n, (250.0, 0.0, AREA_WIDTH_CM, 250.0), rng)
    base = lab_effects(rng)
    effects = Effects(
        exposure=base.exposure,
        auto_exposure=base.auto_exposure,
        flicker=base.flicker,
        compression=Compression(quality=80),
    )
    return _setup("lens", seed, frames, looks, plans, effects, camera=lens_camera())


def build_daylight(seed: int, n: int, frames: int) -> SimSetup:
    """Colour under local light: blue drives back and forth through a strong warm sunlit patch, red circles inside
    it by the sun's glare, green stops and goes in and out of it. Half the lamps go off
    for 4 s (the sunlit patch then outshines the lamps' light 2.5 times), the auto-exposure lags and the automatic white
    balance drifts with the sun and the clouds. A grey and a white box are put down in the area (one in the sun):
    neither may ever be taken for a marker."""
    rng = _rng("daylight", seed)
    looks = fleet_looks(n)
    camera = paper_camera()
    sun = SunPatch(
        strength=1.4,
        clear_bgr=(0.62, 0.85, 1.0),
        cloud_phase=float(rng.uniform(0, 1)),
        cloud_depth=0.6,
    )
    gx, gy = sun_mirror_point(camera.position_cm, sun)
    designed = [
        circle(
            (160.0 + _jitter(rng, 5), 290.0 + _jitter(rng, 5)),
            30.0,
            laps=3.0,
            speed_cm_s=16.0,
            start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
            ccw=bool(rng.random() < 0.5),
        ),
        stop_and_go(
            Pose(300.0, 440.0 + _jitter(rng, 10), -math.pi / 2),
            [(265.0, 320.0 + _jitter(rng, 10)), (320.0, 300.0), (300.0, 440.0)],
            speed_cm_s=20.0,
        ),
        diagonal(
            (40.0 + _jitter(rng, 10), 212.0 + _jitter(rng, 3)),
            (360.0 + _jitter(rng, 10), 212.0 + _jitter(rng, 3)),
            speed_cm_s=24.0,
            come_back=True,
        ),
    ]
    t_off = float(rng.uniform(4.0, 6.0))
    effects = Effects(
        exposure=Exposure(exposure_s=1.0 / 60.0),
        auto_exposure=AutoExposure(),
        auto_white_balance=AutoWhiteBalance(),
        sun=sun,
        glare=Glare(x_cm=gx, y_cm=gy),
        drift=IlluminationDrift(amplitude=0.0, switches=((t_off, t_off + 4.0, 0.55),)),
        props=(
            Prop(70.0 + _jitter(rng, 10), 330.0 + _jitter(rng, 10), albedo_bgr=(0.52, 0.52, 0.52), appears_s=2.0),
            Prop(205.0, 350.0 + _jitter(rng, 5), (30.0, 25.0, 20.0), 0.4, (0.86, 0.86, 0.85), appears_s=3.0),
        ),
    )
    plans = _with_extras(designed, n, (0.0, 440.0, AREA_WIDTH_CM, AREA_LENGTH_CM), rng)
    return _setup("daylight", seed, frames, looks, plans, effects, camera=camera)


def build_crowd(seed: int, n: int, frames: int) -> SimSetup:
    rng = _rng("crowd", seed)
    looks = fleet_looks(n)
    return _setup("crowd", seed, frames, looks, grid_circles(n, AREA, rng), lab_effects(rng))


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
) -> SimSetup:
    """The :class:`SimSetup` of scenario ``name`` for ``seed`` (``rovers``/``frames`` default to the scenario's;
    ``heading``: ``plain``, ``two_tone`` or ``aruco`` markers; ``camera``: ``nominal`` or ``family``)."""
    return get_scenario(name).build(seed, rovers, frames, heading, camera)
