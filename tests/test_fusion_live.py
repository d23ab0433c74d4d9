"""The fusion service with real processes on a real Mosquitto: boards publishing detections, two fusers, one of
them publishing; killed, paused and resumed fusers; a board that dies. And `edge-ips start` boards on the wide
arena's simulated cameras, fused into poses that match the world."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from edge.board_messages import parse_fuser_status
from edge.messages import parse_pose, parse_status
from tests.conftest import REPO
from tests.support.mosquitto import Mosquitto
from tests.support.runtime import MqttRecorder, Received, stop_process
from tests.support.synthetic_board import truth

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # real processes and Mosquittos, seconds each

PY = sys.executable
BOARDS = {"a": ("0,0,450,550", "3"), "b": ("350,0,800,550", "-5")}


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return {**env, "PYTHONPATH": str(REPO)}


@contextmanager
def process(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen(
        args, cwd=cwd, env=env or _env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)  # a paused one must be able to stop
        stop_process(proc)


def board(url: str, edge_id: str, cwd: Path) -> list[str]:
    view, offset = BOARDS[edge_id]
    return [PY, "-m", "tests.support.synthetic_board", url, edge_id, view, offset]


def fuser(url: str, fuser_id: str) -> list[str]:
    return [PY, "-m", "edge.cli", "fuse", "--broker", url, "--id", fuser_id]


def fuser_states(messages: list[Received]) -> dict[str, str]:
    """Each fuser's latest retained status state."""
    out: dict[str, str] = {}
    for m in messages:
        if m.topic.startswith("ips/v1/fuser/") and m.topic.endswith("/status"):
            status = parse_fuser_status(m.payload)
            out[status.fuser] = status.state
    return out


def pose_list(messages: list[Received], after_s: float = 0.0) -> list[tuple[float, object]]:
    return [(m.t_recv, parse_pose(m.payload)) for m in messages if m.topic.endswith("/pose") and m.t_recv >= after_s]


def poses_after(recorder: MqttRecorder, t: float, count: int) -> bool:
    return recorder.wait_for(lambda msgs: len(pose_list(msgs, t)) >= count, timeout_s=60.0)


def no_frame_twice(messages: list[Received]) -> None:
    seen: set[tuple[str, int]] = set()
    for _, pose in pose_list(messages):
        key = (pose.id, pose.frame)  # type: ignore[attr-defined]
        assert key not in seen, f"{key} published twice: two fusers at once"
        seen.add(key)


@pytest.fixture
def system(mosquitto: Mosquitto, tmp_path: Path) -> Iterator[tuple[MqttRecorder, dict[str, subprocess.Popen[str]]]]:
    """Two boards, two fusers, a recorder of everything on the broker; wait until one fuser publishes."""
    url = mosquitto.url
    with (
        MqttRecorder("127.0.0.1", mosquitto.port) as recorder,
        process(board(url, "a", tmp_path), tmp_path) as a,
        process(board(url, "b", tmp_path), tmp_path) as b,
        process(fuser(url, "fuser-a"), tmp_path) as fa,
        process(fuser(url, "fuser-b"), tmp_path) as fb,
    ):
        assert recorder.wait_for(lambda msgs: sorted(fuser_states(msgs).values()) == ["active", "standby"], 60.0)
        assert poses_after(recorder, 0.0, 60)
        yield recorder, {"a": a, "b": b, "fuser-a": fa, "fuser-b": fb}


def active(recorder: MqttRecorder) -> str:
    states = fuser_states(recorder.messages)
    (name,) = [f for f, s in states.items() if s == "active"]
    return name


def test_one_fuser_publishes_each_rovers_pose_once_per_frame_where_the_rover_is(system) -> None:  # type: ignore[no-untyped-def]
    recorder, _ = system
    start = recorder.messages[-1].t_recv
    assert poses_after(recorder, start, 300)
    poses = pose_list(recorder.messages, start)
    assert {p.id for _, p in poses} == {"r1", "r2", "r3"}  # type: ignore[attr-defined]
    errors = []
    for t_recv, p in poses:
        assert p.frame == round(p.t * 30.0) % 1_000_000_000  # type: ignore[attr-defined]
        # one machine, one clock: a pose's t (the grab, on the fuser's clock) is before anyone received it
        assert t_recv >= p.t, (t_recv, p)  # type: ignore[attr-defined]
        x, y = truth(p.id, p.t)  # type: ignore[attr-defined]
        errors.append(math.hypot(p.x - x, p.y - y))  # type: ignore[attr-defined]
    # both boards' clocks are wrong (+3 ms, -5 ms): the fuser found out, or r1 would be off by 0.1-0.2 cm more
    assert float(np.mean(errors)) < 0.3 and max(errors) < 1.5
    no_frame_twice(recorder.messages)
    statuses = [
        parse_fuser_status(m.payload) for m in recorder.messages if m.topic.endswith(f"{active(recorder)}/status")
    ]
    offsets = {b.edge: b.offset_ms for b in statuses[-1].boards}
    assert all(b.offset_source != "none" for b in statuses[-1].boards)
    # the boards' clocks are +3 ms and -5 ms off the fuser's: found from the data to the latency of this machine
    assert offsets["a"] == pytest.approx(3.0, abs=3.0) and offsets["b"] == pytest.approx(-5.0, abs=3.0), offsets
    assert offsets["b"] - offsets["a"] == pytest.approx(-8.0, abs=2.5), offsets


@pytest.mark.parametrize("how", ["killed", "paused"])
def test_the_standby_takes_over_and_never_publishes_beside_the_active_one(system, how: str) -> None:  # type: ignore[no-untyped-def]
    recorder, procs = system
    holder = active(recorder)
    other = "fuser-b" if holder == "fuser-a" else "fuser-a"
    t0 = recorder.messages[-1].t_recv
    if how == "killed":
        procs[holder].kill()
    else:
        os.kill(procs[holder].pid, signal.SIGSTOP)
    assert recorder.wait_for(lambda msgs: fuser_states(msgs).get(other) == "active", 30.0)
    assert poses_after(recorder, t0, 150)  # the poses go on, from the other fuser
    if how == "paused":
        t1 = recorder.messages[-1].t_recv
        os.kill(procs[holder].pid, signal.SIGCONT)
        # the resumed fuser learns it lost: it says standby, and publishes nothing that the active one also does
        assert recorder.wait_for(lambda msgs: fuser_states(msgs).get(holder) == "standby", 30.0)
        assert poses_after(recorder, t1, 150)
        assert fuser_states(recorder.messages)[other] == "active"
    no_frame_twice(recorder.messages)


def test_a_board_that_dies_is_reported_with_its_view_and_the_others_go_on(system) -> None:  # type: ignore[no-untyped-def]
    recorder, procs = system
    procs["b"].kill()  # its last will: status offline

    def b_offline(msgs: list[Received]) -> bool:
        latest = [parse_fuser_status(m.payload) for m in msgs if m.topic == f"ips/v1/fuser/{active(recorder)}/status"]
        return bool(latest) and any(b.edge == "b" and b.state == "offline" for b in latest[-1].boards)

    assert recorder.wait_for(b_offline, 30.0)
    status = [
        parse_fuser_status(m.payload) for m in recorder.messages if m.topic.endswith(f"{active(recorder)}/status")
    ][-1]
    (b_state,) = [b for b in status.boards if b.edge == "b"]
    assert b_state.view == [[350.0, 0.0], [800.0, 0.0], [800.0, 550.0], [350.0, 550.0]]  # the area nobody watches
    t0 = recorder.messages[-1].t_recv
    assert poses_after(recorder, t0, 120)
    assert recorder.wait_for(
        lambda msgs: (
            "r3"
            in [parse_fuser_status(m.payload) for m in msgs if m.topic.endswith(f"{active(recorder)}/status")][
                -1
            ].missing
        ),
        30.0,
    )  # r3 circles in b's half only
    later = pose_list(recorder.messages, recorder.messages[-1].t_recv - 1.0)
    assert "r2" in {p.id for _, p in later}  # type: ignore[attr-defined]


def test_edge_ips_start_boards_on_the_wide_arena_and_a_fuser_make_one_map(mosquitto: Mosquitto, tmp_path: Path) -> None:
    """The product path: two `edge-ips start` boards (simulated cameras of one world, edge.publish = detections)
    and `edge-ips fuse` on one broker; the poses are the world's."""
    from edge.sim.wide_source import WideCameraSource

    url = mosquitto.url
    env = {**_env(), "EDGE_IPS_EDGE__PUBLISH": "detections"}

    def start(cam: str) -> list[str]:
        return [
            PY,
            "-m",
            "edge.cli",
            "start",
            "--source",
            f"sim:wide:{cam}:2",
            "--edge-id",
            cam,
            "--broker",
            url,
            "--no-dashboard",
            "--http-port",
            "0",
        ]

    with (
        MqttRecorder("127.0.0.1", mosquitto.port) as recorder,
        process(start("cam1"), tmp_path, env),
        process(start("cam2"), tmp_path, env),
        # this busy machine renders and tracks both cameras: a grab reaches the fuser 100-300 ms later
        process([*fuser(url, "fuser-a"), "--max-age", "1.0"], tmp_path),
    ):
        assert recorder.wait_for(lambda msgs: len({p.id for _, p in pose_list(msgs)}) >= 10, 120.0)  # type: ignore[attr-defined]
        t0 = recorder.messages[-1].t_recv
        assert poses_after(recorder, t0, 200)

        def boards_report_their_rovers(msgs: list[Received]) -> bool:
            said = [
                parse_status(m.payload)
                for m in msgs
                if m.topic.startswith("ips/v1/edge/") and m.topic.endswith("/status")
            ]
            return all(
                any(s.edge == cam and s.state == "online" and s.rovers for s in said) for cam in ("cam1", "cam2")
            )

        assert recorder.wait_for(boards_report_their_rovers, 30.0)
        detections = [m for m in recorder.messages if m.topic.endswith("/detections")]
        statuses = [
            parse_status(m.payload)
            for m in recorder.messages
            if m.topic.startswith("ips/v1/edge/") and m.topic.endswith("/status")
        ]
    assert {m.topic for m in detections} == {"ips/v1/edge/cam1/detections", "ips/v1/edge/cam2/detections"}
    # a board of several does not call the other boards' rovers missing, nor degrade for them
    assert {s.edge for s in statuses} == {"cam1", "cam2"}
    assert all(s.missing == [] for s in statuses)
    world = WideCameraSource("wide:cam1:2", realtime=False)
    errors = []
    for _, p in pose_list(recorder.messages, t0):
        x, y = world.truth_at(p.t)[p.id]  # type: ignore[attr-defined]
        errors.append(math.hypot(p.x - x, p.y - y))  # type: ignore[attr-defined]
    # the boards' own clock errors (a few ms) and a loaded machine's latencies included
    assert float(np.median(errors)) < 1.0, errors
    no_frame_twice(recorder.messages)


def test_doctor_on_the_fuser_checks_every_board_and_its_clock(system, mosquitto: Mosquitto) -> None:  # type: ignore[no-untyped-def]
    recorder, procs = system
    doctor = [PY, "-m", "edge.cli", "doctor", "--fusion", "--broker", mosquitto.url]
    assert recorder.wait_for(lambda msgs: len(fuser_states(msgs)) == 2, 30.0)
    healthy = subprocess.run(doctor, capture_output=True, text=True, env=_env(), timeout=60)
    assert healthy.returncode == 0, healthy.stdout + healthy.stderr
    lines = healthy.stdout.splitlines()
    assert any(line.startswith("OK    fusers") and "standby" in line for line in lines), lines
    (board_a,) = [line for line in lines if "board a" in line]
    assert board_a.startswith(("OK", "WARN")) and "clock +" in board_a  # a's clock is 3 ms ahead
    procs["b"].kill()  # its last will: offline
    assert recorder.wait_for(
        lambda msgs: any(
            b.edge == "b" and b.state == "offline"
            for m in msgs[-40:]
            if m.topic.startswith("ips/v1/fuser/") and m.topic.endswith("/status")
            for b in parse_fuser_status(m.payload).boards
        ),
        30.0,
    )
    broken = subprocess.run(doctor, capture_output=True, text=True, env=_env(), timeout=60)
    assert broken.returncode == 1
    (board_b,) = [line for line in broken.stdout.splitlines() if "board b" in line]
    assert board_b.startswith("FAIL") and "offline" in board_b
