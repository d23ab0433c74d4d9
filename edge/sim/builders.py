"""The scenario builders: each turns a seed, a rover count and a frame count into a :class:`edge.sim.setup.SimSetup`
(the table of scenarios is :mod:`edge.sim.scenarios`)."""

from __future__ import annotations

import math

import numpy as np

from edge.camera import (
    AREA_LENGTH_CM,
    AREA_WIDTH_CM,
    PinholeCamera,
    paper_camera,
)
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
from edge.sim.scene import fleet_looks
from edge.sim.setup import AREA, Run, SimSetup, jitter, lab_effects, make_setup, scenario_rng, with_extras
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
from edge.sim.world import Plan, Pose, Segment, Straight, Wait

# C920-like lens at 1280x720, exaggerated a little so the lens scenario is a real test: barrel distortion (about
# 40 px at the corners), a little tangential distortion and a principal point off the image centre.
LENS_DIST_COEFFS = (-0.12, 0.06, 0.0012, -0.0009, 0.0)
LENS_PRINCIPAL_OFFSET_PX = (9.0, -6.0)


def _lab_plans(rng: np.random.Generator) -> list[Plan]:
    red = circle(
        (115.0 + jitter(rng, 15), 165.0 + jitter(rng, 15)),
        75.0 + jitter(rng, 8),
        laps=1.75,
        speed_cm_s=20.0 + jitter(rng, 3),
        start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
        ccw=bool(rng.random() < 0.5),
    )
    gx = 300.0 + jitter(rng, 15)
    green = stop_and_go(
        Pose(gx, 80.0, math.pi / 2),
        [(gx + 20, 230.0 + jitter(rng, 20)), (gx - 60, 330.0 + jitter(rng, 20)), (gx, 80.0)],
        speed_cm_s=22.0,
        stop_s=1.0,
    )
    blue = diagonal(
        (40.0 + jitter(rng, 10), 320.0 + jitter(rng, 10)),
        (250.0 + jitter(rng, 10), 530.0 + jitter(rng, 10)),
        speed_cm_s=22.0,
        come_back=True,
    )
    return [red, green, blue]


def build_lab(seed: int, n: int, frames: int) -> SimSetup:
    rng = scenario_rng("lab", seed)
    looks = fleet_looks(n)
    plans = _lab_plans(rng) if n <= 3 else grid_circles(n, AREA, rng)
    return make_setup("lab", seed, frames, looks, plans[:n], lab_effects(rng))


def build_drift(seed: int, n: int, frames: int) -> SimSetup:
    rng = scenario_rng("drift", seed)
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
    return make_setup("drift", seed, frames, looks, plans[:n], effects)


def build_sun(seed: int, n: int, frames: int) -> SimSetup:
    """Red circles in the sunlit patch and through the glare; green drives in and out of the patch; blue stops and
    goes under the lamps of the near side while the auto-exposure reacts to the passing clouds and to half the lamps
    being switched off for 3 s."""
    rng = scenario_rng("sun", seed)
    looks = fleet_looks(n)
    camera = paper_camera()
    sun = SunPatch(cloud_phase=float(rng.uniform(0, 1)))
    gx, gy = sun_mirror_point(camera.position_cm, sun)
    designed = [
        circle(
            (160.0 + jitter(rng, 8), 280.0 + jitter(rng, 10)),
            45.0,
            laps=3.0,
            speed_cm_s=18.0,
            start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
            ccw=bool(rng.random() < 0.5),
        ),
        diagonal((255.0, 110.0 + jitter(rng, 15)), (255.0, 470.0 + jitter(rng, 15)), speed_cm_s=22.0, come_back=True),
        stop_and_go(
            Pose(40.0, 95.0 + jitter(rng, 10), 0.0),
            [(200.0, 105.0), (340.0, 90.0 + jitter(rng, 10)), (40.0, 95.0)],
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
    plans = with_extras(designed, n, (0.0, 360.0, 210.0, AREA_LENGTH_CM), rng)
    return make_setup("sun", seed, frames, looks, plans, effects, camera=camera)


def build_cross(seed: int, n: int, frames: int) -> SimSetup:
    """Red and green pass head-on in adjacent lanes (1 cm between bodies); blue crosses a lane right behind them.

    Twice: in the near half of the area, then at its far side (markers ~20 x 9 px).
    """
    rng = scenario_rng("cross", seed)
    looks = fleet_looks(n)
    look = looks[0]
    v = 20.0
    lane = look.body_width_cm + 1.0  # centre to centre: the bodies pass 1 cm apart
    gap = crossing_gap_s(look.body_length_cm, look.body_width_cm, look.body_length_cm, look.body_width_cm, v, 1.0)
    events = [
        ((195.0 + jitter(rng, 20), 200.0 + jitter(rng, 20)), float(rng.uniform(-0.3, 0.3))),
        ((195.0 + jitter(rng, 20), 500.0 + jitter(rng, 10)), float(rng.uniform(-0.3, 0.3))),
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
    plans = with_extras(plans, n, (0.0, 260.0, 90.0, 440.0), rng)
    return make_setup("cross", seed, frames, looks, plans, lab_effects(rng))


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
    rng = scenario_rng("occlusion", seed)
    looks = fleet_looks(n)
    stand = (175.0 + jitter(rng, 15), 230.0 + jitter(rng, 15))
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
    blue_start = Pose(300.0 + jitter(rng, 15), 70.0 + jitter(rng, 10), -math.pi / 2)
    blue = leave_and_return(blue_start, (blue_start.x_cm + 10.0, -75.0), speed_cm_s=30.0, away_s=1.5)
    green = stop_and_go(Pose(60.0, 420.0, 0.0), [(120.0, 500.0), (60.0, 420.0)], speed_cm_s=18.0, stop_s=1.5)
    plans = with_extras([red, green, blue], n, (0.0, 0.0, 110.0, 350.0), rng)
    effects = lab_effects(rng)
    effects = Effects(
        exposure=effects.exposure, auto_exposure=effects.auto_exposure, flicker=effects.flicker, occluders=(person,)
    )
    return make_setup("occlusion", seed, frames, looks, plans, effects)


def lens_camera() -> PinholeCamera:
    """The paper's camera through a real lens: distortion and the principal point off the centre."""
    return paper_camera(LENS_DIST_COEFFS, LENS_PRINCIPAL_OFFSET_PX)


def build_lens(seed: int, n: int, frames: int) -> SimSetup:
    """The paper's diagonal run (Fig. 37) in three parallel lanes, through a distorting lens, MJPG-compressed."""
    rng = scenario_rng("lens", seed)
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
    plans = with_extras(order, n, (250.0, 0.0, AREA_WIDTH_CM, 250.0), rng)
    base = lab_effects(rng)
    effects = Effects(
        exposure=base.exposure,
        auto_exposure=base.auto_exposure,
        flicker=base.flicker,
        compression=Compression(quality=80),
    )
    return make_setup("lens", seed, frames, looks, plans, effects, camera=lens_camera())


def build_daylight(seed: int, n: int, frames: int) -> SimSetup:
    """Colour under local light: blue drives back and forth through a strong warm sunlit patch, red circles inside
    it by the sun's glare, green stops and goes in and out of it. Half the lamps go off
    for 4 s (the sunlit patch then outshines the lamps' light 2.5 times), the auto-exposure lags and the automatic white
    balance drifts with the sun and the clouds. A grey and a white box are put down in the area (one in the sun):
    neither may ever be taken for a marker."""
    rng = scenario_rng("daylight", seed)
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
            (160.0 + jitter(rng, 5), 290.0 + jitter(rng, 5)),
            30.0,
            laps=3.0,
            speed_cm_s=16.0,
            start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
            ccw=bool(rng.random() < 0.5),
        ),
        stop_and_go(
            Pose(300.0, 440.0 + jitter(rng, 10), -math.pi / 2),
            [(265.0, 320.0 + jitter(rng, 10)), (320.0, 300.0), (300.0, 440.0)],
            speed_cm_s=20.0,
        ),
        diagonal(
            (40.0 + jitter(rng, 10), 212.0 + jitter(rng, 3)),
            (360.0 + jitter(rng, 10), 212.0 + jitter(rng, 3)),
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
            Prop(70.0 + jitter(rng, 10), 330.0 + jitter(rng, 10), albedo_bgr=(0.52, 0.52, 0.52), appears_s=2.0),
            Prop(205.0, 350.0 + jitter(rng, 5), (30.0, 25.0, 20.0), 0.4, (0.86, 0.86, 0.85), appears_s=3.0),
        ),
    )
    plans = with_extras(designed, n, (0.0, 440.0, AREA_WIDTH_CM, AREA_LENGTH_CM), rng)
    return make_setup("daylight", seed, frames, looks, plans, effects, camera=camera)


def build_crowd(seed: int, n: int, frames: int) -> SimSetup:
    rng = scenario_rng("crowd", seed)
    looks = fleet_looks(n)
    return make_setup("crowd", seed, frames, looks, grid_circles(n, AREA, rng), lab_effects(rng))
