"""Scripted trajectories of the paper's tests and the hard cases: circles, the diagonal, crossings, stops, leaving.

Every function returns a :class:`edge.sim.world.Plan` (exact, differential-drive feasible, trapezoidal speeds).
Units: cm, s, rad.
"""

from __future__ import annotations

import math

import numpy as np

from edge.errors import SimulationError
from edge.messages import wrap_angle
from edge.sim.world import Arc, GoTo, Plan, Pose, Segment, Straight, Turn, Wait

TAU = 2.0 * math.pi


def circle(
    centre_cm: tuple[float, float],
    radius_cm: float,
    *,
    laps: float = 1.75,
    speed_cm_s: float = 20.0,
    start_angle_rad: float = 0.0,
    ccw: bool = True,
    wait_before_s: float = 1.0,
    wait_after_s: float = 1.0,
    cyclic: bool = False,
) -> Plan:
    """Circular trajectory (the paper's Figs. 33-36): stand, drive ``laps`` times round, stand."""
    cx, cy = centre_cm
    x = cx + radius_cm * math.cos(start_angle_rad)
    y = cy + radius_cm * math.sin(start_angle_rad)
    heading = start_angle_rad + (math.pi / 2 if ccw else -math.pi / 2)
    sign = 1.0 if ccw else -1.0
    segments: list[Segment] = [Wait(wait_before_s), Arc(radius_cm, sign * laps * TAU, speed_cm_s), Wait(wait_after_s)]
    return Plan(Pose(x, y, heading), segments, cyclic=cyclic)


def diagonal(
    start_cm: tuple[float, float],
    end_cm: tuple[float, float],
    *,
    speed_cm_s: float = 25.0,
    wait_before_s: float = 1.0,
    wait_after_s: float = 1.0,
    come_back: bool = False,
) -> Plan:
    """Straight-line trajectory (the paper's Fig. 37: from near (0, 0) to near (391.5, 549.5)); optionally back."""
    dx, dy = end_cm[0] - start_cm[0], end_cm[1] - start_cm[1]
    length = math.hypot(dx, dy)
    if length <= 0:
        raise SimulationError("diagonal: start and end coincide")
    segments: list[Segment] = [Wait(wait_before_s), Straight(length, speed_cm_s), Wait(wait_after_s)]
    if come_back:
        segments += [Turn(math.pi), Straight(length, speed_cm_s), Turn(math.pi), Wait(wait_after_s)]
    return Plan(Pose(start_cm[0], start_cm[1], math.atan2(dy, dx)), segments, cyclic=come_back)


def stop_and_go(
    start: Pose, waypoints_cm: list[tuple[float, float]], *, speed_cm_s: float = 20.0, stop_s: float = 1.0
) -> Plan:
    """Drive to each waypoint in turn (turning on the spot), standing ``stop_s`` at each."""
    segments: list[Segment] = [Wait(stop_s)]
    for x, y in waypoints_cm:
        segments += [GoTo(x, y, speed_cm_s), Wait(stop_s)]
    return Plan(start, segments)


def leave_and_return(
    start: Pose, outside_cm: tuple[float, float], *, speed_cm_s: float = 25.0, away_s: float = 2.0
) -> Plan:
    """Drive out of the camera's view to ``outside_cm``, wait there, turn round and come back to the start."""
    return Plan(
        start,
        [
            Wait(1.0),
            GoTo(outside_cm[0], outside_cm[1], speed_cm_s),
            Wait(away_s),
            GoTo(start.x_cm, start.y_cm, speed_cm_s),
            Wait(1.0),
        ],
    )


def time_to_distance(distance_cm: float, speed_cm_s: float, accel_cm_s2: float = 40.0) -> float:
    """Seconds a straight run from standing takes to cover ``distance_cm`` (of a run twice as long)."""
    probe = Plan(Pose(0.0, 0.0, 0.0), [Straight(2 * distance_cm, speed_cm_s)], accel_cm_s2=accel_cm_s2)
    lo, hi = 0.0, probe.duration_s
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if probe.sample(mid)[0].x_cm < distance_cm:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def transfer(here: Pose, there: Pose, speed_cm_s: float = 30.0) -> list[Segment]:
    """Segments that drive from ``here`` to ``there`` (turn, straight, turn to its heading)."""
    probe = Plan(here, [GoTo(there.x_cm, there.y_cm, speed_cm_s)])
    return [GoTo(there.x_cm, there.y_cm, speed_cm_s), Turn(wrap_angle(there.theta_rad - probe.end_pose.theta_rad))]


def crossing_gap_s(
    first_length_cm: float,
    first_width_cm: float,
    second_length_cm: float,
    second_width_cm: float,
    speed_cm_s: float,
    clearance_cm: float,
) -> float:
    """Delay between two perpendicular rovers (same speed) passing the same point so their bodies clear by
    ``clearance_cm``.

    With the first along x and the second along y, the gaps between the bodies along x and y (``dx``, ``dy``) sum to
    a constant while both are positive: the corners pass diagonally, closest when ``dx = dy``, at a distance
    ``(dx + dy) / sqrt(2)``.
    """
    reach = (first_length_cm + second_width_cm) / 2 + (first_width_cm + second_length_cm) / 2
    return (reach + math.sqrt(2.0) * clearance_cm) / speed_cm_s


def grid_circles(
    n: int,
    region_cm: tuple[float, float, float, float],
    rng: np.random.Generator,
    *,
    body_radius_cm: float = 16.5,
    laps: float = 3.0,
) -> list[Plan]:
    """``n`` rovers each circling in its own cell of a grid over ``region_cm`` (x0, y0, x1, y1), never touching.

    Cells are as square as the region allows; each circle is as large as its cell permits less the body's reach,
    with a random direction, start angle and speed (seeded by ``rng``).
    """
    x0, y0, x1, y1 = region_cm
    width, height = x1 - x0, y1 - y0
    cols = max(1, round(math.sqrt(n * width / height)))
    rows = math.ceil(n / cols)
    while (cols - 1) * rows >= n and cols > 1:
        cols -= 1
    cell_w, cell_h = width / cols, height / rows
    radius = 0.5 * min(cell_w, cell_h) - body_radius_cm - 1.5
    if radius < 8.0:
        raise SimulationError(
            f"{n} rovers do not fit in the region {region_cm} (cells of {cell_w:.0f} x {cell_h:.0f} cm)"
        )
    plans = []
    for k in range(n):
        r, c = divmod(k, cols)
        centre = (x0 + (c + 0.5) * cell_w, y0 + (r + 0.5) * cell_h)
        # Inner wheel speed limit: v * (1 + track / (2 r)) <= 35 cm/s with a 15 cm track.
        top = 34.0 / (1.0 + 7.5 / radius)
        plans.append(
            circle(
                centre,
                radius,
                laps=laps,
                speed_cm_s=float(min(top, rng.uniform(14.0, 24.0))),
                start_angle_rad=float(rng.uniform(0, TAU)),
                ccw=bool(rng.random() < 0.5),
                wait_before_s=float(rng.uniform(0.3, 1.5)),
                cyclic=True,
            )
        )
    return plans
