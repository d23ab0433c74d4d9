"""The live twin end to end, with real processes: ``edge-ips start --source sim:twin`` tracks the lab's camera and
publishes poses; each rover's real firmware, its own MQTT client with its own login, drives its body by what it
receives. Once through the embedded broker (the lab started by the edge, the rovers on the state directory's
logins), once through a Mosquitto set up by ``edge-ips broker-config`` (the lab started by hand with its logins).

Formations (all three through the embedded broker, the triangle through Mosquitto) are commanded through the
dashboard's HTTP API and judged on the poses as published, by the bars of the
closed-loop experiments (docs/experiments.md): line within 3 cm, rendezvous inside 40 cm, triangle 100 +- 3 cm, by
frame 240 of the formation. STOP, sent while the rovers drive, must leave every rover at rest within 0.5 s (the
poses from then on move less than the tracker's noise), on the poses and on the lab's ground truth.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import time
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path

import pytest

from edge.sim.twin.source import LabClient
from tests.support.command import EDGE_IPS, Edge, arrival, wait_reports
from tests.support.dashboard import call, clean_env
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder
from tests.support.twin import (
    TOPICS,
    Poses,
    Twin,
    TwinLabProcess,
    formation_run,
    rest_events,
    stop_run,
    wait_tracked,
)

pytestmark = [pytest.mark.slow, pytest.mark.realtime]

ROVERS = ["red", "green", "blue"]
TOKEN = "twin-e2e-dashboard-token"
AUTH = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
EDGE_ID = f"twin-{os.getpid() % 100_000}"
FRAMES = 300  # observed per formation; the bar must hold from frame 240 on
AT_REST_AFTER_S = 0.5
REST_WINDOW_S = 1.0
REST_CM = 1.0  # a standing rover's poses move by the tracker's noise (p95 0.22 cm), far less than this
TRUTH_CM = 1.0  # a standing rover's pose from its true place: the tracker's error (p95 0.3 cm in the closed loop)


@pytest.fixture(params=["embedded", "mosquitto"])
def twin(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Twin]:
    state = tmp_path / "s"
    env = {"EDGE_IPS_DASHBOARD__TOKEN": TOKEN, "EDGE_IPS_EDGE__ID": EDGE_ID, "EDGE_IPS_EDGE__STATE_DIR": str(state)}
    lab = LabClient(state / "twin.sock")
    if request.param == "embedded":
        port = free_port()
        edge = Edge(["--source", "sim:twin"], clean_env(EDGE_IPS_BROKER__EMBEDDED_PORT=str(port), **env), tmp_path)
        edge.start()
        rec = MqttRecorder("127.0.0.1", port, topics=TOPICS).start()  # anonymous from this machine: read-only
        try:
            yield Twin(edge, lab, rec, Poses(rec), "embedded")
        finally:
            rec.stop()
            edge.stop()
        return
    conf = tmp_path / "broker"
    done = subprocess.run(
        [*EDGE_IPS, "broker-config", "--out", str(conf), "--rovers", ",".join(ROVERS)],
        cwd=tmp_path,
        env=clean_env(EDGE_IPS_EDGE__ID=EDGE_ID),
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    logins = tomllib.loads((conf / "credentials.toml").read_text())
    with Mosquitto(tmp_path / "mosquitto", conf_path=conf / "mosquitto.conf") as broker:
        rovers_port = broker.ports[1883]  # the network listener: a rover's client id is its user name there
        lab_process = TwinLabProcess(
            ["--broker", f"mqtt://127.0.0.1:{rovers_port}", "--credentials", str(conf / "credentials.toml")],
            state,
            tmp_path / "lab",
        ).start()
        edge_login = logins["edge"]
        url = f"mqtt://{edge_login['username']}:{edge_login['password']}@127.0.0.1:{broker.port}"
        edge = Edge(["--source", "sim:twin", "--broker", url], clean_env(**env), tmp_path)
        viewer = logins["viewer"]
        rec = MqttRecorder("127.0.0.1", rovers_port, TOPICS, viewer["username"], viewer["password"])
        try:
            edge.start()
            rec.start()
            yield Twin(edge, lab, rec, Poses(rec), "mosquitto")
        finally:
            rec.stop()
            edge.stop()
            lab_process.stop()


def _scatter(twin: Twin) -> float:
    t = time.time()
    twin.lab.scatter()
    wait_tracked(twin.poses, ROVERS, t)
    return t


def _why(twin: Twin, after: float) -> dict[str, object]:
    """For a failure's message: how late the poses since ``after`` reached the observer (from their frame's time at
    the edge: p50, p95, max, ms) and what the rovers said meanwhile (their halt reasons)."""
    late = sorted(1000.0 * (p.t_recv - p.t) for p in twin.poses.since(after))
    said = [m.payload.decode() for m in list(twin.rec.messages) if m.topic.endswith("/status") and m.t_recv >= after]
    if not late:
        return {"statuses": said}
    pick = [late[min(len(late) - 1, int(q * len(late)))] for q in (0.5, 0.95)]
    return {"pose_latency_ms": [round(v) for v in (*pick, late[-1])], "statuses": said}


def _moving(twin: Twin, after: float) -> None:
    """Until a rover drives at 10 cm/s or more (by its poses)."""
    twin.poses.wait(lambda ps: any(p.speed > 10.0 for p in twin.poses.since(after)), "a rover driving")


def test_the_dashboards_formations_meet_the_closed_loop_bars_and_stop_leaves_every_rover_at_rest(
    twin: Twin, record_property: Callable[[str, object], None]
) -> None:
    results = []
    stops = []
    # every formation through the embedded broker; through Mosquitto the hardest, the triangle (the formation law
    # does not depend on the broker: what does is the command's and the poses' path, and the STOP)
    kinds = ("line", "rendezvous", "triangle") if twin.broker == "embedded" else ("triangle",)
    for kind in kinds:
        after = _scatter(twin)
        sent = twin.edge.command(kind, TOKEN, ROVERS)
        t_command = arrival(twin.rec, kind, sent["seq"], after)
        run = formation_run(twin.poses, ROVERS, kind, t_command, FRAMES)
        results.append(asdict(run))
        assert run.holds_by(240), (run, _why(twin, t_command))

        # The retained formation still holds: scattered again, the rovers drive back; STOP while they do.
        after = _scatter(twin)
        _moving(twin, after)
        t_stop = time.time()
        twin.edge.command("stop", TOKEN)
        moved = stop_run(twin.poses, ROVERS, t_stop, AT_REST_AFTER_S, REST_WINDOW_S)
        stops.append({"after": kind, "moved_cm": {r: round(v, 2) for r, v in moved.items()}})
        assert all(v < REST_CM for v in moved.values()), moved
        truth = twin.lab.status()["rovers"]
        assert not [r["id"] for r in truth if r["moving"]], truth  # the lab's ground truth agrees
        # ...and the poses the rovers act on are where the rovers stand (at rest: no latency in the comparison)
        last = {p.id: p for p in twin.poses.since(t_stop)}
        off = {r["id"]: math.hypot(last[r["id"]].x - r["truth"]["x"], last[r["id"]].y - r["truth"]["y"]) for r in truth}
        assert max(off.values()) < TRUTH_CM, off
    record_property("broker", twin.broker)
    record_property("formations", results)
    record_property("stops", stops)


# -- faults ----------------------------------------------------------------------------------------------------------
BOUND_S = 0.5  # every rover at rest within this of its last fresh pose (docs/firmware.md)


def _rest_times(twin: Twin, label: str, after: int, rovers: list[str]) -> dict[str, float]:
    """For the rovers that were driving when ``label`` happened: the time from each one's last fresh pose to rest
    (at least one must have been driving)."""
    driving = {r: rest["after_pose_s"] for r, rest in rest_events(twin.lab, label, after, rovers).items() if rest}
    assert driving, f"no rover was driving when {label}"
    return driving


def _fault(twin: Twin, body: dict[str, object]) -> str:
    reply = call(twin.edge.http_port, "POST", "/api/sim/fault", json.dumps(body).encode(), AUTH)
    assert reply.status == 200, reply.body
    return str(reply.json()["done"])


def _driving(twin: Twin, kind: str) -> None:
    """The fleet commanded ``kind``, scattered, and driving back to it."""
    after = _scatter(twin)
    sent = twin.edge.command(kind, TOKEN, ROVERS)
    arrival(twin.rec, kind, sent["seq"], after)
    _moving(twin, after)


@pytest.mark.parametrize("twin", ["embedded"], indirect=True)
def test_every_fault_stops_the_rovers_within_the_bound_and_they_come_back(
    twin: Twin, record_property: Callable[[str, object], None]
) -> None:
    stops: dict[str, dict[str, float]] = {}

    # The camera hangs: no poses, every rover stops; the frames come back and they drive on.
    _driving(twin, "rendezvous")
    mark = twin.lab.status()["events"][-1]["n"]
    label = _fault(twin, {"kind": "camera", "seconds": 2})
    stops["camera"] = _rest_times(twin, label, mark, ROVERS)
    _moving(twin, time.time() + 2.0)

    # One rover's Wi-Fi goes for 3 s (the association holds): it stops, the others drive on; then it does too.
    _driving(twin, "triangle")
    mark = twin.lab.status()["events"][-1]["n"]
    label = _fault(twin, {"kind": "wifi", "seconds": 3, "rover": "green"})
    stops["wifi"] = _rest_times(twin, label, mark, ["green"])
    twin.poses.wait(lambda ps: any(p.id == "green" and p.speed > 10.0 for p in ps[-30:]), "green driving again")

    # The edge is killed and started again 3 s later: the embedded broker goes with it, every rover stops; the
    # restarted edge's retained stop keeps them halted until commanded.
    _driving(twin, "line")
    mark = twin.lab.status()["events"][-1]["n"]
    t_kill = time.time()
    label = _fault(twin, {"kind": "edge", "seconds": 3})
    stops["edge"] = _rest_times(twin, label, mark, ROVERS)
    wait_reports(twin.rec, ROVERS, "stop", 1, t_kill)  # back: the new edge's stop at start, seq 1 (no retained one)

    # The embedded broker restarts: every rover stops at once (its connection ends), reconnects, and reports.
    _driving(twin, "rendezvous")
    mark = twin.lab.status()["events"][-1]["n"]
    t_restart = time.time()
    label = _fault(twin, {"kind": "broker", "seconds": 2})
    stops["broker"] = _rest_times(twin, label, mark, ROVERS)
    twin.rec.wait_for(
        lambda ms: all(any(m.t_recv > t_restart + 2 and f"/{r}/status" in m.topic for m in ms) for r in ROVERS), 180
    )

    record_property("rest_after_last_fresh_pose_s", stops)
    late = {fault: times for fault, times in stops.items() if max(times.values()) > BOUND_S}
    assert not late, stops
