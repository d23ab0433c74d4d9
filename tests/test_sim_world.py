"""The simulated world: scripted plans and wheel-commanded differential-drive rovers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.errors import SimulationError
from edge.messages import wrap_angle
from edge.sim.trajectories import circle, crossing_gap_s, diagonal, leave_and_return, time_to_distance
from edge.sim.world import (
    Arc,
    DriveModel,
    GoTo,
    Plan,
    Pose,
    Straight,
    Turn,
    Wait,
    WheelCommand,
    World,
)

START = Pose(100.0, 100.0, 0.0)


@pytest.mark.parametrize(
    ("segments", "end"),
    [
        ([Straight(100.0)], (200.0, 100.0, 0.0)),
        ([Straight(-50.0)], (50.0, 100.0, 0.0)),
        ([Arc(50.0, math.pi / 2)], (150.0, 150.0, math.pi / 2)),
        ([Arc(50.0, -math.pi / 2)], (150.0, 50.0, -math.pi / 2)),
        ([Turn(math.pi / 2), Straight(30.0)], (100.0, 130.0, math.pi / 2)),
        ([Wait(2.0)], (100.0, 100.0, 0.0)),
        ([GoTo(100.0, 0.0)], (100.0, 0.0, -math.pi / 2)),
        ([Straight(40.0), Arc(20.0, math.pi), Straight(40.0)], (100.0, 140.0, math.pi)),
    ],
)
def test_plan_ends_where_its_segments_say(segments, end):
    plan = Plan(START, segments)
    pose, v, omega = plan.sample(plan.duration_s + 1.0)
    assert (pose.x_cm, pose.y_cm) == pytest.approx(end[:2], abs=1e-9)
    assert wrap_angle(pose.theta_rad - end[2]) == pytest.approx(0.0, abs=1e-9)
    assert (v, omega) == (0.0, 0.0)


@pytest.mark.parametrize(
    "segments",
    [
        [Straight(120.0, 25.0), Arc(40.0, 2.0, 20.0), Straight(30.0, 15.0)],
        [Wait(0.5), GoTo(200.0, 300.0, 30.0), Turn(-1.0), Arc(60.0, -4.0, 22.0)],
    ],
)
def test_plan_velocity_is_the_derivative_of_its_position(segments):
    # The ground truth's vx, vy must be what the rover really does between frames.
    plan = Plan(START, segments, accel_cm_s2=40.0)
    dt = 1e-4
    for t in np.linspace(0.01, plan.duration_s - 0.01, 300):
        p0, _, _ = plan.sample(t - dt)
        p1, v, omega = plan.sample(t + dt)
        pm, _, _ = plan.sample(t)
        vx = (p1.x_cm - p0.x_cm) / (2 * dt)
        vy = (p1.y_cm - p0.y_cm) / (2 * dt)
        assert vx == pytest.approx(v * math.cos(pm.theta_rad), abs=0.05)
        assert vy == pytest.approx(v * math.sin(pm.theta_rad), abs=0.05)
        assert wrap_angle(p1.theta_rad - p0.theta_rad) / (2 * dt) == pytest.approx(omega, abs=0.01)


def test_plan_speed_ramps_no_faster_than_its_acceleration():
    plan = Plan(START, [Straight(200.0, 25.0), Arc(30.0, 3.0, 25.0), Straight(50.0, 10.0)], accel_cm_s2=40.0)
    ts = np.arange(0.0, plan.duration_s, 0.01)
    speeds = np.array([plan.sample(t)[1] for t in ts])
    assert np.max(np.abs(np.diff(speeds))) / 0.01 <= 40.0 + 1e-6
    assert speeds.max() == pytest.approx(25.0)


def test_cyclic_plan_repeats():
    plan = circle((200.0, 200.0), 50.0, laps=1.0, cyclic=True)
    a, _, _ = plan.sample(1.3)
    b, _, _ = plan.sample(1.3 + 3 * plan.duration_s)
    assert (a.x_cm, a.y_cm, a.theta_rad) == pytest.approx((b.x_cm, b.y_cm, b.theta_rad), abs=1e-9)


def test_circle_stays_on_its_circle_and_turns_the_right_way():
    plan = circle((150.0, 250.0), 80.0, laps=1.5, ccw=False)
    for t in np.linspace(0, plan.duration_s, 50):
        pose, _, omega = plan.sample(t)
        assert math.hypot(pose.x_cm - 150.0, pose.y_cm - 250.0) == pytest.approx(80.0, abs=1e-9)
        assert omega <= 1e-12


def test_diagonal_is_the_papers_fig_37_line():
    plan = diagonal((0.0, 0.0), (391.5, 549.5), speed_cm_s=25.0)
    for t in np.linspace(0, plan.duration_s, 40):
        pose, _, _ = plan.sample(t)
        assert pose.x_cm * 549.5 - pose.y_cm * 391.5 == pytest.approx(0.0, abs=1e-6)
    assert (plan.end_pose.x_cm, plan.end_pose.y_cm) == pytest.approx((391.5, 549.5))


def test_leave_and_return_comes_back_to_its_start():
    start = Pose(300.0, 110.0, -math.pi / 2)
    plan = leave_and_return(start, (320.0, -90.0))
    mid, _, _ = plan.sample(plan.duration_s * 0.5)
    assert mid.y_cm < -50.0
    assert (plan.end_pose.x_cm, plan.end_pose.y_cm) == pytest.approx((300.0, 110.0))


def test_time_to_distance_includes_the_ramp():
    # 40 cm/s^2 to 20 cm/s: 0.5 s and 5 cm of ramp, then 65 cm at 20 cm/s
    assert time_to_distance(70.0, 20.0) == pytest.approx(0.5 + 65.0 / 20.0, abs=1e-6)


def test_crossing_gap_keeps_perpendicular_bodies_apart():
    v, clearance = 20.0, 1.0
    gap = crossing_gap_s(25.0, 20.0, 25.0, 20.0, v, clearance)
    # first rover along +x through the origin at t=0, second along +y at t=gap
    worst = np.inf
    for t in np.linspace(-5, 5, 20001):
        xa, yb = v * t, v * (t - gap)
        dx = abs(xa) - (25.0 + 20.0) / 2
        dy = abs(yb) - (20.0 + 25.0) / 2
        distance = math.hypot(dx, dy) if dx > 0 and dy > 0 else max(dx, dy)
        worst = min(worst, distance)
    assert worst == pytest.approx(clearance, abs=0.01)


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (lambda: Plan(START, [Straight(10.0, 0.0)]), "speed must be positive"),
        (lambda: Plan(START, [Arc(-5.0, 1.0)]), "radius must be positive"),
        (lambda: Plan(START, [Wait(-1.0)]), "must not be negative"),
        (lambda: DriveModel(track_width_cm=0.0), "must be positive"),
        (lambda: World({}), "at least one rover"),
    ],
)
def test_bad_plans_and_models_are_refused_with_a_clear_message(bad, message):
    with pytest.raises(SimulationError, match=message):
        bad()


def test_world_refuses_a_plan_beyond_the_wheel_speed_limit():
    fast = Plan(START, [Arc(10.0, 3.0, 30.0)])  # outer wheel 30 * (1 + 7.5 / 10) = 52.5 cm/s
    with pytest.raises(SimulationError, match=r"red.*52\.5 cm/s"):
        World({"red": fast}, DriveModel(max_wheel_speed_cm_s=35.0))


# -- wheel commands ---------------------------------------------------------------------------------------------
IDEAL = DriveModel(max_wheel_accel_cm_s2=None)


@pytest.mark.parametrize(("v", "omega"), [(20.0, 0.0), (20.0, 0.5), (-10.0, 0.3), (0.0, 1.0), (15.0, -0.8)])
def test_commanded_rover_follows_the_unicycle_exactly(v, omega):
    world = World({"a": Pose(50.0, 60.0, 0.4)}, IDEAL)
    for _ in range(30):
        state = world.step(1 / 30, {"a": (v, omega)})
    r = state.rovers[0]
    t, th0 = 1.0, 0.4
    if abs(omega) < 1e-12:
        x, y = 50 + v * t * math.cos(th0), 60 + v * t * math.sin(th0)
    else:
        x = 50 + v / omega * (math.sin(th0 + omega * t) - math.sin(th0))
        y = 60 - v / omega * (math.cos(th0 + omega * t) - math.cos(th0))
    assert (r.x_cm, r.y_cm) == pytest.approx((x, y), abs=1e-6)
    assert wrap_angle(r.theta_rad - th0 - omega * t) == pytest.approx(0.0, abs=1e-9)
    assert (r.vx_cm_s, r.vy_cm_s) == pytest.approx((v * math.cos(r.theta_rad), v * math.sin(r.theta_rad)), abs=1e-9)


def test_wheel_speed_limit_saturates_commands():
    world = World({"a": Pose(0.0, 0.0, 0.0)}, DriveModel(max_wheel_speed_cm_s=30.0, max_wheel_accel_cm_s2=None))
    state = world.step(1.0, {"a": WheelCommand(100.0, 100.0)})
    assert state.rovers[0].v_cm_s == pytest.approx(30.0)
    assert state.rovers[0].x_cm == pytest.approx(30.0)


def test_wheel_acceleration_limit_ramps_speed():
    world = World({"a": Pose(0.0, 0.0, 0.0)}, DriveModel(max_wheel_accel_cm_s2=100.0))
    state = world.step(0.1, {"a": WheelCommand(30.0, 30.0)})
    assert state.rovers[0].v_cm_s == pytest.approx(10.0)
    state = world.step(0.5)
    assert state.rovers[0].v_cm_s == pytest.approx(30.0)


def test_actuation_delay_holds_the_old_command():
    world = World({"a": Pose(0.0, 0.0, 0.0)}, DriveModel(max_wheel_accel_cm_s2=None, delay_s=0.1))
    state = world.step(0.05, {"a": (20.0, 0.0)})
    assert state.rovers[0].x_cm == pytest.approx(0.0)
    state = world.step(0.15)
    assert state.rovers[0].x_cm == pytest.approx(20.0 * 0.1, abs=1e-9)


def test_dead_band_keeps_slow_set_points_from_moving_the_wheel():
    world = World({"a": Pose(0.0, 0.0, 0.0)}, DriveModel(max_wheel_accel_cm_s2=None, deadband_cm_s=3.0))
    assert world.step(1.0, {"a": WheelCommand(2.0, 2.0)}).rovers[0].x_cm == 0.0


def test_motor_gain_error_curves_a_straight_command_and_is_fixed_by_the_seed():
    drive = DriveModel(max_wheel_accel_cm_s2=None, motor_gain_sigma=0.05)
    ends = []
    for seed in (1, 1, 2):
        world = World({"a": Pose(0.0, 0.0, 0.0)}, drive, seed=seed)
        ends.append(world.step(3.0, {"a": (20.0, 0.0)}).rovers[0])
    assert ends[0] == ends[1]
    assert ends[0] != ends[2]
    assert abs(ends[0].theta_rad) > 1e-3  # unequal wheels turn a "straight" run


def test_commanding_an_unknown_rover_names_the_known_ones():
    world = World({"a": Pose(0.0, 0.0, 0.0), "b": Plan(START, [Wait(1.0)])})
    with pytest.raises(SimulationError, match=r"'zz'.*commanded rovers: a"):
        world.step(0.1, {"zz": (1.0, 0.0)})


def test_scripted_world_can_be_sampled_at_any_time_but_a_commanded_one_cannot():
    scripted = World({"a": circle((100.0, 100.0), 30.0)})
    assert scripted.state_at(2.0) == scripted.state_at(2.0)
    with pytest.raises(SimulationError, match="state_at"):
        World({"a": Pose(0.0, 0.0, 0.0)}).state_at(1.0)


@pytest.mark.parametrize(
    ("angle", "wrapped"),
    [(0.0, 0.0), (math.pi, math.pi), (-math.pi, math.pi), (3 * math.pi, math.pi), (7.0, 7.0 - 2 * math.pi)],
)
def test_wrap_angle_returns_minus_pi_exclusive_to_pi(angle, wrapped):
    assert wrap_angle(angle) == pytest.approx(wrapped)
