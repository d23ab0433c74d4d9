"""Real processes for the command path's end-to-end tests: ``edge-ips start`` (killed and restarted),
``edge-ips sim rovers``, ``edge-ips formation``, and an observer of the rovers' statuses and the formation topic.

Every wait is on messages (the observer's condition variable), bounded by a generous failure timeout.
"""

from __future__ import annotations

import contextlib
import json
import queue
import signal
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from edge.messages import FORMATION_TOPIC, ROVER_STATUS_WILDCARD
from tests.support.dashboard import EdgeProcess, PortTaken, call, clean_env, edge_start
from tests.support.runtime import MqttRecorder, Received, stop_process

EDGE_IPS = [sys.executable, "-m", "edge.cli"]
TIMEOUT_S = 120.0  # failure guard only: how long a rover may take to report before the test gives up


def observer(host: str, port: int, username: str | None = None, password: str | None = None) -> MqttRecorder:
    """Every formation message and rover status, with its arrival time (reconnects across broker restarts)."""
    return MqttRecorder(
        host, port, topics=(FORMATION_TOPIC, ROVER_STATUS_WILDCARD), username=username, password=password
    )


def retained_now(host: str, port: int, username: str | None = None, password: str | None = None) -> dict[str, Any]:
    """The formation the broker holds now, as a client subscribing now gets it."""
    got: queue.Queue[bytes] = queue.Queue()
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="late-subscriber")
    if username is not None:
        client.username_pw_set(username, password)
    client.on_connect = lambda c, u, f, rc, p: c.subscribe(FORMATION_TOPIC, qos=1)
    client.on_message = lambda c, u, m: got.put(bytes(m.payload)) if m.retain else None
    client.connect(host, port)
    client.loop_start()
    try:
        return dict(json.loads(got.get(timeout=TIMEOUT_S)))
    finally:
        client.loop_stop()
        client.disconnect()


def formations(rec: MqttRecorder, after: float = 0.0) -> list[tuple[Received, dict[str, Any]]]:
    return [(m, json.loads(m.payload)) for m in rec.on(FORMATION_TOPIC) if m.t_recv >= after and m.payload]


def arrival(rec: MqttRecorder, kind: str, seq: int, after: float) -> float:
    """When the formation (kind, seq) reached the observer (the broker's delivery of the command), first after
    ``after``; waits for it."""
    found: list[float] = []

    def seen(_: list[Received]) -> bool:
        found[:] = [m.t_recv for m, doc in formations(rec, after) if (doc["kind"], doc["seq"]) == (kind, seq)]
        return bool(found)

    assert rec.wait_for(seen, TIMEOUT_S), f"formation {kind} {seq} never reached the broker's subscribers"
    return found[0]


def rover_reports(rec: MqttRecorder, after: float) -> dict[str, list[tuple[float, dict[str, Any]]]]:
    """Each rover's statuses that arrived after ``after``, in order."""
    out: dict[str, list[tuple[float, dict[str, Any]]]] = {}
    for m in rec.on("/status"):
        if m.topic.startswith("ips/v2/rovers/") and m.t_recv >= after and m.payload:
            doc = json.loads(m.payload)
            out.setdefault(doc["id"], []).append((m.t_recv, doc))
    return out


def wait_reports(rec: MqttRecorder, rovers: Sequence[str], kind: str, seq: int, after: float) -> dict[str, float]:
    """Wait until every rover reports it applies (kind, seq) (a stop: with halt stop) in a status that arrived after
    ``after``; returns when each one's first such status arrived."""
    first: dict[str, float] = {}

    def done(_: list[Received]) -> bool:
        for rover_id, reports in rover_reports(rec, after).items():
            for t, doc in reports:
                ok = (doc["formation"], doc["seq"]) == (kind, seq) and doc["state"] == "online"
                if ok and (kind != "stop" or doc["halt"] == "stop") and rover_id not in first:
                    first[rover_id] = t
        return all(r in first for r in rovers)

    if not rec.wait_for(done, TIMEOUT_S):
        latest = {r: reps[-1][1] for r, reps in rover_reports(rec, after).items()}
        raise AssertionError(f"not every rover reports {kind} (seq {seq}): latest {latest}")
    return first


class Edge:
    """``edge-ips start`` as a subprocess (:func:`tests.support.dashboard.edge_start`: online, dashboard on a free
    port; ``env`` names the edge with ``EDGE_IPS_EDGE__ID``); :meth:`kill` is a crash (SIGKILL), :meth:`start`
    again a restart."""

    def __init__(self, args: list[str], env: dict[str, str], workdir: Path) -> None:
        self.args, self.env, self.workdir = args, env, workdir
        self._stack = contextlib.ExitStack()
        self.process: EdgeProcess | None = None
        self.starts = 0

    def start(self) -> Edge:
        """Start and wait until online. Other processes on this machine pick free ports too: when one takes the
        dashboard's port first (ours then exits, "already in use"), start again on another."""
        for _ in range(3):
            self.starts += 1
            try:
                process = self._stack.enter_context(
                    edge_start(self.args, self.workdir / f"edge-{self.starts}", self.env)
                )
            except PortTaken:
                continue
            token = self.env.get("EDGE_IPS_DASHBOARD__TOKEN")
            auth = {"Authorization": f"Bearer {token}"} if token else {}
            state = call(process.http_port, "GET", "/api/state", headers=auth)
            assert state.status == 200 and state.json()["edge_id"] == self.env["EDGE_IPS_EDGE__ID"], state
            self.process = process
            return self
        raise AssertionError("three ports in a row were taken by other processes")

    @property
    def http_port(self) -> int:
        assert self.process is not None
        return self.process.http_port

    def kill(self) -> None:
        assert self.process is not None
        self.process.proc.send_signal(signal.SIGKILL)
        self.process.proc.wait(30)

    def stop(self) -> None:
        self._stack.close()

    def command(self, kind: str, token: str, ids: Sequence[str] = ()) -> dict[str, Any]:
        """What the page's buttons post, with the token: its STOP ``/api/stop``, the formations ``/api/formation``;
        returns the published message."""
        auth = {"Authorization": f"Bearer {token}"}
        if kind == "stop":
            reply = call(self.http_port, "POST", "/api/stop", b"", auth)
        else:
            body = json.dumps({"kind": kind, "ids": list(ids)}).encode()
            reply = call(self.http_port, "POST", "/api/formation", body, auth)
        assert reply.status == 200, reply.body
        return dict(reply.json()["formation"])


def cli_formation(kind: str, broker_url: str, workdir: Path) -> dict[str, Any]:
    """``edge-ips formation KIND --broker URL``: the message it published."""
    done = subprocess.run(
        [*EDGE_IPS, "formation", kind, "--broker", broker_url],
        cwd=workdir,
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


@dataclass
class SimRovers:
    """``edge-ips sim rovers`` as a subprocess; :meth:`stop` is Ctrl-C."""

    args: list[str]
    workdir: Path
    proc: subprocess.Popen[str] | None = None
    out: Path = field(init=False)

    def start(self) -> SimRovers:
        self.out = self.workdir / "sim-rovers.out"
        with self.out.open("w") as out:
            self.proc = subprocess.Popen(
                [*EDGE_IPS, "sim", "rovers", *self.args],
                cwd=self.workdir,
                env=clean_env(),
                stdout=out,
                stderr=subprocess.STDOUT,
                text=True,
            )
        return self

    def stop(self) -> int:
        """SIGINT (Ctrl-C), then the exit code."""
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(60)
        finally:
            stop_process(self.proc)

    def output(self) -> str:
        return self.out.read_text(errors="replace")
