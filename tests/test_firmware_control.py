"""The formation law (firmware/esp8266/formation.py) and the rover's safety rules (rover.py), under CPython.

Closed-loop runs use :class:`firmware.harness.runner.KinematicFleet`: each rover's real firmware drives a kinematic
differential-drive body; poses carry measurement noise and latency, motors a gain error. Time is simulated.
"""

from __future__ import annotations

import itertools
import math
import random
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge import messages
from edge.rover_host import HostRover, firmware_modules
from firmware.harness.runner import (
    Body,
    KinematicFleet,
    assert_formation_bars,
    enclosing_diameter,
    formation_run,
    random_starts,
    rover_configs,
)

fw = firmware_modules()
fm: Any = fw["formation"]
motors: Any = fw["motors"]
rv: Any = fw["rover"]

IDS = ["red", "green", "blue"]
BODY_RADIUS_CM = 14.0  # the example configs' geometry.body_radius_cm: bodies touch below twice this
SAFETY_CM = 30.0


def formation(kind: str, ids: list[str] = IDS, seq: int = 1, **fields: Any) -> dict[str, Any]:
    doc = {"seq": seq, "kind": kind, "ids": ids, "spacing": None, "side": None, "x": None, "y": None, "theta": None}
    return {**doc, **fields}


# -- the pieces ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("v", "w", "left", "right"),
    [
        (10.0, 0.0, 10 / 3.25, 10 / 3.25),  # straight
        (0.0, 1.0, -6.5 / 3.25, 6.5 / 3.25),  # turn in place, counter-clockwise: right wheel forward
        (-5.0, 0.0, -5 / 3.25, -5 / 3.25),
    ],
)
def test_wheel_speeds_follow_radius_and_track(v: float, w: float, left: float, right: float) -> None:
    got = fm.wheels(v, w, 3.25, 13.0, 100.0)
    assert got == pytest.approx((left, right))
    assert fm.body_motion(*got, 3.25, 13.0) == pytest.approx((v, w))


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.floats(-500, 500), st.floats(-20, 20), st.floats(1, 30))
def test_wheel_saturation_keeps_the_curvature_and_the_limit(v: float, w: float, limit: float) -> None:
    left, right = fm.wheels(v, w, 3.25, 13.0, limit)
    assert max(abs(left), abs(right)) <= limit + 1e-9
    free_l, free_r = fm.wheels(v, w, 3.25, 13.0, 1e9)
    scale = max(abs(free_l), abs(free_r))
    if scale > limit:  # scaled down together: same ratio, same turning radius
        assert left * free_r == pytest.approx(right * free_l, abs=1e-6)
        assert max(abs(left), abs(right)) == pytest.approx(limit)
    else:
        assert (left, right) == pytest.approx((free_l, free_r))


@pytest.mark.parametrize(
    ("theta", "u", "v", "w"),
    [
        (0.0, (10.0, 0.0), 10.0, 0.0),  # look-ahead point pushed straight ahead
        (0.0, (0.0, 6.0), 0.0, 1.0),  # sideways: turn, with l = 6 cm
        (math.pi / 2, (0.0, -10.0), -10.0, 0.0),  # backwards
    ],
)
def test_single_integrator_maps_to_the_unicycle_through_the_look_ahead_point(
    theta: float, u: tuple[float, float], v: float, w: float
) -> None:
    assert fm.unicycle(u[0], u[1], theta, 6.0) == pytest.approx((v, w), abs=1e-12)


@pytest.mark.parametrize(
    ("x", "theta", "v", "expect"),
    [
        (0.0, 0.0, 20.0, "limited"),  # neighbour 32 cm straight ahead: may approach only at the barrier's pace
        (0.0, math.pi, 20.0, "free"),  # driving away from it
        (0.0, math.pi / 2, 20.0, "free"),  # passing it side-on: the distance does not shrink
        (3.0, 0.0, 20.0, "backs off"),  # already inside the safety distance: must back away
    ],
)
def test_the_barrier_only_limits_motion_towards_a_neighbour(x: float, theta: float, v: float, expect: str) -> None:
    got = fm.safe_speed(v, x, 0.0, theta, [32.0], [0.0], 1, SAFETY_CM, 4.0)
    if expect == "free":
        assert got == v
    elif expect == "limited":
        h = 32.0**2 - SAFETY_CM**2
        assert got == pytest.approx(0.5 * 4.0 * h / (2 * 32.0))
    else:
        assert got < 0


def test_a_rover_squeezed_between_two_too_close_neighbours_stands_still() -> None:
    assert fm.safe_speed(10.0, 0.0, 0.0, 0.0, [25.0, -25.0], [0.0, 0.0], 2, SAFETY_CM, 4.0) == 0.0


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-200, 200), st.floats(-200, 200)), min_size=1, max_size=6),
    st.floats(-math.pi, math.pi),
    st.floats(-100, 100),
)
def test_no_command_lets_the_distance_to_a_neighbour_shrink_faster_than_the_barrier_allows(
    others: list[tuple[float, float]], theta: float, v: float
) -> None:
    qx = [p[0] for p in others]
    qy = [p[1] for p in others]
    others_ok = all(math.hypot(x, y) >= SAFETY_CM for x, y in others)
    got = fm.safe_speed(v, 0.0, 0.0, theta, qx, qy, len(qx), SAFETY_CM, 4.0)
    if not others_ok:
        return
    for x, y in others:
        # d/dt |p - q|^2 = 2 (p - q) . e v >= -(gamma / 2) h
        rate = 2 * ((0 - x) * math.cos(theta) + (0 - y) * math.sin(theta)) * got
        assert rate >= -0.5 * 4.0 * (x * x + y * y - SAFETY_CM**2) - 1e-6


@pytest.mark.parametrize(
    ("kind", "n", "length", "neighbour_gap"),
    [
        (fm._LINE, 3, 60.0, 60.0),
        (fm._LINE, 5, 40.0, 40.0),
        (fm._TRIANGLE, 3, 100.0, 100.0),
        (fm._RENDEZVOUS, 3, 31.0, 31.0),
        (fm._RENDEZVOUS, 6, 31.0, 31.0),
        (fm._TRIANGLE, 2, 100.0, 100.0),
    ],
)
def test_formation_offsets_have_the_commanded_spacing_and_are_centred(
    kind: int, n: int, length: float, neighbour_gap: float
) -> None:
    bx = [0.0] * n
    by = [0.0] * n
    fm.offsets(kind, n, length, length, length, bx, by)
    pts = np.column_stack([bx, by])
    assert np.allclose(pts.mean(axis=0), 0.0, atol=1e-9)
    gaps = np.linalg.norm(pts - np.roll(pts, -1, axis=0), axis=1)[: n if kind != fm._LINE and n > 2 else n - 1]
    assert np.allclose(gaps, neighbour_gap)


@settings(max_examples=100, deadline=None)
@given(st.floats(-math.pi, math.pi), st.booleans(), st.floats(-300, 300), st.floats(-300, 300))
def test_a_free_triangle_is_fitted_to_where_the_rovers_already_are(
    angle: float, mirrored: bool, tx: float, ty: float
) -> None:
    bx = [0.0] * 3
    by = [0.0] * 3
    fm.offsets(fm._TRIANGLE, 3, 0.0, 100.0, 0.0, bx, by)
    c, s = math.cos(angle), math.sin(angle)
    px = [c * (-x if mirrored else x) - s * y + tx for x, y in zip(bx, by, strict=True)]
    py = [s * (-x if mirrored else x) + c * y + ty for x, y in zip(bx, by, strict=True)]
    cx = [0.0] * 3
    cy = [0.0] * 3
    fm.orient(fm._TRIANGLE, None, px, py, bx, by, 3, cx, cy)
    # Already in formation: the law asks for nothing.
    for i in range(3):
        assert fm.consensus(i, px, py, cx, cy, 3, 0.8) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_consensus_is_the_papers_displacement_law() -> None:
    rng = np.random.default_rng(1)
    p = rng.uniform(0, 300, (4, 2))
    c = rng.uniform(-50, 50, (4, 2))
    for i in range(4):
        want = 0.7 * sum((p[j] - p[i]) - (c[j] - c[i]) for j in range(4) if j != i)
        got = fm.consensus(i, list(p[:, 0]), list(p[:, 1]), list(c[:, 0]), list(c[:, 1]), 4, 0.7)
        assert got == pytest.approx(tuple(want))


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.floats(-30, 30), st.integers(0, 600))
def test_the_duty_model_inverts(speed_rad_s: float, deadband: int) -> None:
    duty = motors.duty_for_speed(speed_rad_s, 15.0, deadband, 0.3)
    back = motors.speed_for_duty(duty, speed_rad_s >= 0, 15.0, deadband)
    assert 0 <= duty <= 1023
    if abs(speed_rad_s) < 0.3:
        assert duty == 0 and back == 0.0
    elif abs(speed_rad_s) >= 15.0:
        assert duty == 1023 and back == pytest.approx(math.copysign(15.0, speed_rad_s))
    else:
        assert back == pytest.approx(speed_rad_s, abs=0.5 * 15.0 / (1023 - deadband) + 1e-9)


@pytest.mark.parametrize("turn_rad_s", [0.0, 0.3, -0.5])
def test_heading_is_learnt_from_successive_positions_while_moving(turn_rad_s: float) -> None:
    h = fm.Heading(6.0)
    body = Body(100.0, 100.0, 0.9)
    v = 10.0
    for _ in range(60):  # 2 s at 30 Hz, poses without heading
        h.moved(v, turn_rad_s, 1 / 30, 0.5)
        dt = 1 / 30
        body.x += v * math.cos(body.theta + turn_rad_s * dt / 2) * dt
        body.y += v * math.sin(body.theta + turn_rad_s * dt / 2) * dt
        body.theta += turn_rad_s * dt
        h.measured(body.x, body.y, None)
    assert h.known
    assert abs(fm.wrap(h.theta - body.theta)) < math.radians(3)


# -- closed loop ---------------------------------------------------------------------------------------------------
CASES = [
    (kind, seed, theta)
    for kind in ("line", "rendezvous", "triangle")
    for seed, theta in ((1, True), (2, False), (3, False))
]


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "seed", "send_theta"), CASES)
def test_the_fleet_converges_from_random_starts_and_bodies_never_touch(kind: str, seed: int, send_theta: bool) -> None:
    fleet = formation_run(kind, seed, send_theta=send_theta)
    assert_formation_bars(kind, fleet.positions())
    assert fleet.trace.min_distance_cm >= 2 * BODY_RADIUS_CM
    assert all(h == "none" for h in fleet.trace.halts[-1])


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "send_theta"), [(0, True), (1, True), (2, False), (3, False)])
def test_six_rovers_crowding_to_a_rendezvous_never_touch(seed: int, send_theta: bool) -> None:
    ids = ["a", "b", "c", "d", "e", "f"]
    starts = random_starts(6, random.Random(seed), min_gap_cm=45.0)
    fleet = KinematicFleet(
        rover_configs(ids), starts, seed=seed, noise_cm=0.5, latency_ms=60, motor_noise=0.1, send_theta=send_theta
    )
    fleet.command(formation("rendezvous", ids))
    fleet.run(25.0)
    assert fleet.trace.min_distance_cm >= 2 * BODY_RADIUS_CM
    # Gathered round the ring of six (side: safety + 4 gaps = 34 cm, 68 cm across), though a crowd whose poses
    # carry no heading may still be sorting itself out: rovers that must re-learn their heading by driving wait
    # until they have room.
    assert enclosing_diameter(fleet.positions()) <= 100.0


def test_two_rovers_swapping_ends_of_a_line_pass_each_other() -> None:
    # red must end at the bottom and blue at the top of a fixed vertical line; they start the other way round.
    starts = [Body(195.0, 400.0, -math.pi / 2), Body(195.0, 150.0, math.pi / 2)]
    fleet = KinematicFleet(rover_configs(["red", "blue"]), starts, seed=1, noise_cm=0.3, latency_ms=50, send_theta=True)
    fleet.command(formation("line", ["red", "blue"], spacing=100.0, x=195.0, theta=0.0))
    fleet.run(15.0)
    (rx, ry), (bx, by) = fleet.positions()
    assert ry < by and abs((by - ry) - 100.0) < 3.0 and abs(rx - 195.0) < 3.0 and abs(bx - 195.0) < 3.0
    assert fleet.trace.min_distance_cm >= 2 * BODY_RADIUS_CM


# -- safety rules ----------------------------------------------------------------------------------------------------
def _moving_fleet() -> KinematicFleet:
    fleet = KinematicFleet(
        rover_configs(IDS), random_starts(3, random.Random(9)), seed=9, latency_ms=30, send_theta=True
    )
    fleet.command(formation("triangle", side=100.0))
    fleet.run(1.0)
    assert all(r.halt == "none" for r in fleet.rovers)
    return fleet


def test_motors_stop_within_half_a_second_of_the_last_young_own_pose() -> None:
    fleet = _moving_fleet()
    fleet.publishing = False
    fleet.run(0.2)
    last_rx = fleet.now_ms  # everything in flight has been delivered by now
    stopped_at = {}
    while fleet.now_ms < last_rx + 1000:
        fleet.run(0.001)
        for r in fleet.rovers:
            if r.motor_state.left_duty == 0 and r.motor_state.right_duty == 0 and r.id not in stopped_at:
                stopped_at[r.id] = fleet.now_ms
                assert r.halt == "stale"
    latest_pose_rx = max(max(r.rover._stamp) for r in fleet.rovers)
    for rid, t in stopped_at.items():
        assert t - latest_pose_rx <= 500, rid  # stale_ms (0.4 s) plus at most one 20 ms loop period: inside 0.5 s
    assert set(stopped_at) == set(IDS)


def test_a_rover_whose_pose_ages_slows_down_along_its_command_and_is_still_when_cut() -> None:
    fleet = _moving_fleet()
    fleet.publishing = False
    fleet.run(0.1)  # what was in flight (30 ms latency) has arrived
    trace: dict[str, list[tuple[int, float, float]]] = {r.id: [] for r in fleet.rovers}  # (age ms, scale, duty)
    while fleet.now_ms < max(max(r.rover._stamp) for r in fleet.rovers) + 600:
        fleet.run(0.02)
        for r in fleet.rovers:
            age = r.rover._last_step - r.rover._stamp[r.rover._me]  # at its last step
            trace[r.id].append((age, r.rover._scale, r.motor_state.left_duty + r.motor_state.right_duty))
    control = fleet.rovers[0].config["control"]
    fade, stale = control["fade_ms"], control["stale_ms"]
    for rid, rows in trace.items():
        fading = [(age, k, duty) for age, k, duty in rows if fade < age <= stale]
        assert fading, rid
        for age, k, _ in fading:  # the share of the command falls linearly from 1 at fade_ms to 0 at stale_ms
            assert k == pytest.approx((stale - age) / (stale - fade), abs=0.1), (rid, age)
        duties = [duty for _, _, duty in fading]
        assert all(b <= a for a, b in itertools.pairwise(duties)), (rid, duties)
        assert all(duty == 0 for age, _, duty in rows if age > stale), rid
        assert [r.halt for r in fleet.rovers if r.id == rid] == ["stale"]


@pytest.mark.parametrize("edge_clock_s", [1.0, 1763900000.0 - 3600.0, 9999990000.0])
def test_the_edge_clock_may_be_anything_only_pose_ages_count(edge_clock_s: float) -> None:
    # Poses stamped by an edge clock an hour behind, near 1970 or near the contract's limit: the rover shares no
    # clock with the edge and uses t only to compare poses' ages, so it drives on poses that arrive as they are made.
    rover = HostRover(rover_configs(["red"])[0], broker_host=None)
    rover.deliver("ips/v1/formation", b'{"v":1,"seq":1,"kind":"rendezvous","ids":["red","blue"]}', 0)
    for k in range(30):
        now = k * 33
        for rid, x in (("red", 100.0), ("blue", 300.0)):
            payload = messages.encode_pose(rid, k, k, edge_clock_s + now / 1000, x, 100.0, 0.0, None, None, 1.0)
            rover.deliver(f"ips/v1/rovers/{rid}/pose", payload, now)
        rover.step(now)
    assert rover.halt == "none"
    assert rover.motor_state.left_duty > 0


def test_a_pose_whose_capture_time_stands_still_ages_and_stops_the_rover() -> None:
    # Poses that keep arriving but were all captured at the same moment (what a backlog looks like, drawn out): by
    # arrival they would be fresh; by age the rover stops once the newest is stale_ms older than the first.
    rover = HostRover(rover_configs(["red"])[0], broker_host=None)
    rover.deliver("ips/v1/formation", b'{"v":1,"seq":1,"kind":"rendezvous","ids":["red","blue"]}', 0)
    halts = []
    for k in range(30):
        now = k * 33
        for rid, x in (("red", 100.0), ("blue", 300.0)):
            payload = messages.encode_pose(rid, k, k, 1763900000.0, x, 100.0, 0.0, None, None, 1.0)
            rover.deliver(f"ips/v1/rovers/{rid}/pose", payload, now)
        rover.step(now)
        halts.append((now, rover.halt))
    stale_ms = rover.config["control"]["stale_ms"]
    assert all(h == "stale" for now, h in halts if now > stale_ms)
    assert rover.motor_state.left_duty == 0 and rover.motor_state.right_duty == 0


def test_a_stop_formation_halts_every_rover_at_the_next_step() -> None:
    fleet = _moving_fleet()
    fleet.command(formation("stop", [], seq=2))
    fleet.run(0.021)
    for r in fleet.rovers:
        assert r.halt == "stop"
        assert r.motor_state.left_duty == 0 and r.motor_state.right_duty == 0


def test_a_rover_left_out_of_the_formation_stays_put() -> None:
    fleet = _moving_fleet()
    fleet.command(formation("rendezvous", ["green", "blue"], seq=2))
    fleet.run(0.5)
    red = fleet.rovers[0]
    assert red.halt == "idle" and red.motor_state.left_duty == 0


def test_the_newest_formation_seq_wins_and_a_redelivered_one_is_not_reapplied() -> None:
    rover = HostRover(rover_configs(["red"])[0], broker_host=None)
    rover.deliver("ips/v1/formation", b'{"v":1,"seq":7,"kind":"line","ids":["red"],"spacing":60}', 0)
    rover.deliver("ips/v1/formation", b'{"v":1,"seq":7,"kind":"line","ids":["red"],"spacing":60}', 10)
    rover.deliver("ips/v1/formation", b'{"v":1,"seq":8,"kind":"stop","ids":[]}', 20)
    assert [line for line in rover.log_lines if line.startswith("formation")] == [
        "formation 7 line ['red']",
        "formation 8 stop []",
    ]


class _FailingMotors:
    def __init__(self) -> None:
        self.fail = True
        self.stops = 0

    def drive(self, left: float, right: float) -> None:
        if self.fail:
            raise RuntimeError("H-bridge fault")

    def stop(self) -> None:
        self.stops += 1


def test_an_exception_in_the_loop_stops_the_motors_is_logged_and_the_loop_goes_on() -> None:
    lines: list[str] = []
    m = _FailingMotors()
    rover = rv.Rover(rover_configs(["red"])[0], m, log=lambda *a: lines.append(" ".join(map(str, a))))
    rover.on_message(b"ips/v1/formation", b'{"v":1,"seq":1,"kind":"rendezvous","ids":["red","blue"]}')
    for k in range(5):
        rover._now = k * 20
        for rid, x in (("red", 100.0), ("blue", 300.0)):
            pose = f'{{"v":1,"id":"{rid}","seq":{k},"frame":{k},"t":1.0,"x":{x},"y":100,"theta":0,"vx":null,'
            rover.on_message(f"ips/v1/rovers/{rid}/pose".encode(), (pose + '"vy":null,"q":1}').encode())
        rover.step(k * 20)
        if k == 2:
            assert rover.halt == "error" and m.stops >= 1
            assert any("H-bridge fault" in line for line in lines)
            m.fail = False
    assert rover.halt == "none"


class _DownLink:
    up = False

    def poll(self, now_ms: int) -> bool:
        return False

    def publish_status(self, payload: bytes) -> None:
        raise AssertionError("nothing is published while the link is down")


def test_motors_stop_while_the_broker_link_is_down() -> None:
    host = HostRover(rover_configs(["red"])[0], broker_host=None)
    host.deliver("ips/v1/formation", b'{"v":1,"seq":1,"kind":"rendezvous","ids":["red","blue"]}', 0)
    host.rover.link = _DownLink()
    host.deliver(
        "ips/v1/rovers/red/pose",
        b'{"v":1,"id":"red","seq":1,"frame":1,"t":1,"x":1,"y":1,"theta":0,"vx":null,"vy":null,"q":1}',
        0,
    )
    host.step(0)
    assert host.halt == "disconnected"
    assert host.motor_state.left_duty == 0 and host.motor_state.right_duty == 0
