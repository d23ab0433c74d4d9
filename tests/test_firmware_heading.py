"""The firmware's heading estimate (formation.Heading): odometry, pose headings and the signed direction of motion
fused so that no single source is trusted blindly; in CPython, in closed loop, and inside a real MicroPython.

The scenarios drive a body as the firmware commands it and feed the firmware what a tracker would send: the body's
heading (a two-tone marker), the direction of motion (a one-colour marker: the opposite of the body's heading while
it backs up), nothing (standing, one-colour), or a wrong heading (glare).
"""

from __future__ import annotations

import json
import math
import random
from typing import Any

import pytest

from edge.rover_host import firmware_modules
from firmware.harness.runner import (
    Body,
    KinematicFleet,
    assert_formation_bars,
    formation_run,
    random_starts,
    rover_configs,
    run_micropython,
)

fm: Any = firmware_modules()["formation"]

IDS = ["red", "green", "blue"]
DT = 1.0 / 30.0


def drive(h: Any, body: Body, v: float, w: float, frames: int, theta_of: Any) -> list[float]:
    """Command (v, w) for ``frames`` frames: the body moves exactly as commanded, the firmware integrates the
    command (moved) and gets a pose per frame whose heading is ``theta_of(body, dx, dy)``; returns the estimate's
    error (rad) after each pose."""
    errors = []
    for _ in range(frames):
        h.moved(v, w, DT, 0.5)
        x0, y0 = body.x, body.y
        mid = body.theta + 0.5 * w * DT
        body.x += v * math.cos(mid) * DT
        body.y += v * math.sin(mid) * DT
        body.theta = math.remainder(body.theta + w * DT, math.tau)
        h.measured(body.x, body.y, theta_of(body, body.x - x0, body.y - y0))
        errors.append(abs(fm.wrap(h.theta - body.theta)))
    return errors


def body_heading(body: Body, dx: float, dy: float) -> float:
    return body.theta


def motion_heading(body: Body, dx: float, dy: float) -> float | None:
    """What the tracker reports for a one-colour marker: the direction of motion while faster than 3 cm/s."""
    return math.atan2(dy, dx) if math.hypot(dx, dy) / DT > 3.0 else None


def no_heading(body: Body, dx: float, dy: float) -> None:
    return None


def known(theta: float) -> Any:
    h = fm.Heading(6.0)
    h.measured(100.0, 100.0, theta)
    assert h.known and abs(fm.wrap(h.theta - theta)) < 1e-9
    return h


@pytest.mark.parametrize(
    ("name", "v", "w", "theta_of"),
    [
        ("reversing, motion headings", -15.0, 0.0, motion_heading),
        ("reversing while turning, motion headings", -12.0, 0.6, motion_heading),
        ("reversing, no headings (chords signed by the command)", -15.0, 0.0, no_heading),
        ("forward, motion headings", 20.0, -0.5, motion_heading),
        ("turning in place, no headings (odometry)", 0.0, 1.5, no_heading),
        ("turning in place, body headings", 0.0, -2.0, body_heading),
    ],
)
def test_the_estimate_follows_the_body_whatever_the_poses_carry(name: str, v: float, w: float, theta_of: Any) -> None:
    body = Body(150.0, 200.0, 0.8)
    h = known(body.theta)
    errors = drive(h, body, v, w, 90, theta_of)  # 3 s
    assert max(errors) < math.radians(5.0), name
    assert h.spread < 1.2  # the rover keeps driving: no re-learning (rover.py relearns past 1.2 rad)


def test_a_rover_that_learnt_its_heading_backing_up_learns_the_body_heading() -> None:
    """Heading unknown, the rover commands reverse: the first chord is the body's heading, not the motion's."""
    body = Body(150.0, 200.0, -2.0)
    h = fm.Heading(6.0)
    drive(h, body, -15.0, 0.0, 30, no_heading)
    assert h.known
    assert abs(fm.wrap(h.theta - body.theta)) < math.radians(5.0)


@pytest.mark.parametrize("wrong_by_deg", [40.0, -40.0, 90.0, 180.0])
@pytest.mark.parametrize("burst", [1, 3, 5])
def test_pose_headings_far_from_the_prediction_are_set_aside(wrong_by_deg: float, burst: int) -> None:
    """A tracker fooled by glare for a few frames: the estimate holds (odometry), and the outliers are counted."""
    body = Body(150.0, 200.0, 0.3)
    h = known(body.theta)
    drive(h, body, 0.0, 0.8, 15, body_heading)  # turning in place: no chord of its own motion to confirm it
    errors = drive(h, body, 0.0, 0.8, burst, lambda b, dx, dy: b.theta + math.radians(wrong_by_deg))
    assert max(errors) < math.radians(3.0)
    assert h.rejected == burst
    errors = drive(h, body, 0.0, 0.8, 10, body_heading)
    assert max(errors) < math.radians(3.0) and h.rejected == 0


@pytest.mark.parametrize("wrong_by_deg", [60.0, 180.0])
def test_pose_headings_that_persist_win_over_a_wrong_estimate(wrong_by_deg: float) -> None:
    """The estimate was wrong (a rover turned by hand while standing): once `recover` poses in a row agree with
    each other against it, they are taken."""
    body = Body(150.0, 200.0, 1.0)
    h = known(body.theta + math.radians(wrong_by_deg))
    errors = drive(h, body, 0.0, 0.0, 10, body_heading)
    assert errors[h.recover - 2] > math.radians(wrong_by_deg - 1.0)  # still held before the last of them
    assert errors[h.recover - 1] < math.radians(1.0)  # taken at the recover-th
    assert max(errors[h.recover - 1 :]) < math.radians(1.0)


def test_outliers_that_disagree_with_each_other_are_never_taken() -> None:
    body = Body(150.0, 200.0, 1.0)
    h = known(body.theta)
    rng = random.Random(3)
    for k in range(60):  # each one on the other side of the truth from the last
        drive(h, body, 0.0, 0.0, 1, lambda b, dx, dy, sign=(-1) ** k: b.theta + sign * rng.uniform(0.7, 1.2))
    assert abs(fm.wrap(h.theta - body.theta)) < 1e-6


def test_a_wrong_estimate_is_corrected_by_its_own_motion() -> None:
    """Wrong by 180 degrees and no pose headings: two chords, signed by the command, against it turn it round."""
    body = Body(150.0, 200.0, 0.5)
    h = known(body.theta + math.pi)
    errors = drive(h, body, 20.0, 0.0, 45, no_heading)
    assert errors[-1] < math.radians(5.0)


def test_pose_headings_are_blended_with_odometry_not_copied() -> None:
    """Noisy pose headings (3 deg) around the truth: the fused estimate is steadier than any one of them."""
    rng = random.Random(7)
    body = Body(150.0, 200.0, 0.0)
    h = known(body.theta)
    errors = drive(h, body, 15.0, 0.3, 300, lambda b, dx, dy: b.theta + rng.gauss(0.0, math.radians(3.0)))
    rms = math.sqrt(sum(e * e for e in errors[30:]) / len(errors[30:]))
    assert rms < math.radians(2.0)


# -- closed loop: the real firmware, kinematic bodies ---------------------------------------------------------------
def _converges(kind: str, seed: int, **kw: Any) -> KinematicFleet:
    return formation_run(kind, seed, 8.0, **kw)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "seed", "poses"),
    [
        ("line", 21, "motion"),
        ("rendezvous", 22, "motion"),
        ("triangle", 23, "motion"),
        ("line", 24, "outliers"),
        ("rendezvous", 25, "outliers"),
        ("triangle", 26, "outliers"),
    ],
)
def test_formations_converge_within_8_s_with_motion_headings_or_outliers(kind: str, seed: int, poses: str) -> None:
    kw = {"motion_theta": True} if poses == "motion" else {"send_theta": True, "theta_outliers": 0.1}
    fleet = _converges(kind, seed, **kw)
    assert_formation_bars(kind, fleet.positions())
    assert fleet.trace.min_distance_cm >= 28.0
    if poses == "outliers":
        assert fleet.outliers_sent > 50  # ten per cent of about 700 headings: the test exercised the gate


@pytest.mark.slow
@pytest.mark.parametrize("poses", ["motion", "outliers"])
def test_micropython_fuses_headings_exactly_as_cpython(poses: str) -> None:
    kw = {"motion_theta": True} if poses == "motion" else {"send_theta": True, "theta_outliers": 0.1}
    fleet = KinematicFleet(
        rover_configs(IDS), random_starts(3, random.Random(41)), seed=41, noise_cm=0.3, latency_ms=40, **kw
    )
    fleet.command({"seq": 1, "kind": "line", "ids": IDS, "spacing": 60.0, "side": None, "x": None, "y": None,
                   "theta": None})  # fmt: skip
    fleet.run(4.0)
    events = json.dumps(fleet.rovers[0].config) + "\n" + "\n".join(fleet.events) + "\n"
    rows = [json.loads(line) for line in run_micropython("replay.main()", {"events": events.encode()}).splitlines()]
    assert len(rows) == len(fleet.commands) > 150
    for (t_ms, halt, command, _), row in zip(fleet.commands, rows, strict=True):
        assert row[0] == t_ms and row[1] == halt
        assert row[2:8] == pytest.approx(command, abs=1e-9)
    assert {row[1] for row in rows} >= {"none"}
