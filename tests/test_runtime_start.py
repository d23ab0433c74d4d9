"""`edge-ips start` for real: the simulator, the tracking pipeline, a real broker, `mosquitto_sub` in another process.

The issue's "done when": `edge-ips start --source sim` publishes live poses that a `mosquitto_sub` shows.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from edge.messages import parse_pose, parse_status
from edge.sim.source import SimSource
from tests.conftest import REPO
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder, poses, stop_process

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # end to end, or long: left out of the quick loop (-m 'not slow')

EDGE_IPS = [sys.executable, "-m", "edge.cli"]  # this checkout's edge-ips


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return {**env, **extra}


@contextmanager
def edge_process(args: list[str], cwd: Path, env: dict[str, str]) -> Iterator[subprocess.Popen[str]]:
    """``edge-ips start --http-port 0 ARGS`` in ``cwd``, stopped with SIGTERM at the end. Its output goes to files
    there (:func:`output`), not to pipes: a pipe nobody reads fills, and an edge that then writes a log line blocks
    (the live twin's test once waited 30 s for an exit after SIGTERM, under a loaded suite)."""
    with open(cwd / "edge.out", "w") as out, open(cwd / "edge.err", "w") as err:
        proc = subprocess.Popen(
            [*EDGE_IPS, "start", "--http-port", "0", *args],
            cwd=cwd,
            env={**env, "PYTHONPATH": str(REPO)},
            stdout=out,
            stderr=err,
            text=True,
        )
        try:
            yield proc
        finally:
            stop_process(proc)


def output(cwd: Path) -> tuple[str, str]:
    """What :func:`edge_process` in ``cwd`` wrote to its stdout and stderr."""
    return (cwd / "edge.out").read_text(), (cwd / "edge.err").read_text()


def exit_code(proc: subprocess.Popen[str], cwd: Path, timeout_s: float) -> int:
    """``proc``'s exit code; a failure with its log's end if it has not exited within ``timeout_s`` (a failure
    guard, not a bar)."""
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        tail = "\n".join(output(cwd)[1].splitlines()[-30:])
        raise AssertionError(f"edge-ips start had not exited within {timeout_s:.0f} s; its log ends:\n{tail}") from None


def test_start_with_the_simulator_publishes_live_poses_that_mosquitto_sub_shows(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    with edge_process(["--source", "sim", "--broker", mosquitto.url], tmp_path, _env()) as edge:
        sub = ["mosquitto_sub", "-h", "127.0.0.1", "-p", str(mosquitto.port), "-t", "ips/v1/rovers/+/pose", "-v"]
        shown = subprocess.run(
            [*sub, "-C", "60", "-W", "120"],
            capture_output=True,
            text=True,
            timeout=150,
        )
        edge.send_signal(signal.SIGTERM)
        assert exit_code(edge, tmp_path, 30) == 0
    lines = shown.stdout.strip().splitlines()
    assert len(lines) == 60, shown.stderr
    truth_source = SimSource("lab", seed=0, realtime=False)
    truth_source.open()
    errors = []
    for line in lines:
        topic, payload = line.split(" ", 1)
        pose = parse_pose(payload.encode())
        assert topic == f"ips/v1/rovers/{pose.id}/pose"
        truth_source.render(pose.frame)
        truth = truth_source.truth(pose.frame).by_id()[pose.id]
        errors.append(np.hypot(pose.x - truth.x_cm, pose.y - truth.y_cm))
    assert {json.loads(ln.split(" ", 1)[1])["id"] for ln in lines} == {"red", "green", "blue"}
    assert float(np.median(errors)) < 2.0, f"poses far from the simulator's truth: {errors}"


def test_start_with_no_configuration_runs_the_live_twin_and_the_embedded_broker(tmp_path: Path) -> None:
    port = free_port()
    env = _env(EDGE_IPS_BROKER__EMBEDDED_PORT=str(port))
    with edge_process([], tmp_path, env) as edge, MqttRecorder("127.0.0.1", port) as rec:
        assert rec.wait_for(lambda m: len(poses(m)) >= 30, 90)
        assert rec.wait_for(lambda m: any(b'"state":"online","camera":"ok"' in x.payload for x in m), 30)
        edge.send_signal(signal.SIGTERM)
        assert exit_code(edge, tmp_path, 30) == 0
    stdout, stderr = output(tmp_path)
    assert stdout.splitlines()[0].startswith("dashboard: http://localhost:PORT/?token=")  # the token made for it
    first = stderr.splitlines()[0]
    assert "source sim:twin (no configuration found, so the live twin; " in first
    camera = sorted(Path("/dev").glob("video*"))  # what the machine has decides the hint
    hint = f"a camera is attached at {camera[0]}" if camera else "no camera is attached: plug one in and use --source"
    assert hint in first
    assert "broker embedded" in first
    statuses = [parse_status(m.payload) for m in rec.messages if m.topic == "ips/v1/edge/edge-1/status"]
    assert statuses and all(s.edge == "edge-1" for s in statuses)


def test_start_refuses_wrong_broker_credentials_before_starting(tmp_path: Path) -> None:
    with Mosquitto(tmp_path / "mq", users={"edge": "right"}) as broker:
        url = f"mqtt://edge:wrong@127.0.0.1:{broker.port}"
        with edge_process(["--source", "sim", "--broker", url], tmp_path, _env()) as edge:
            assert exit_code(edge, tmp_path, 120) == 2
    _, stderr = output(tmp_path)
    assert stderr.strip().splitlines()[-1].startswith("Error: broker mqtt://edge@127.0.0.1")
    assert "refused" in stderr and "wrong" not in stderr and "Traceback" not in stderr
