"""STOP always stops, end to end with real processes: ``edge-ips start`` (killed with SIGKILL and restarted), the
rovers' real firmware in ``edge-ips sim rovers`` (each its own MQTT client with its own credentials), the
dashboard's HTTP API and ``edge-ips formation``; once through a Mosquitto with the users and ACLs of
``edge-ips broker-config`` (rovers provisioned by ``edge-ips flash --bundle``), once through the embedded broker.

Every wait is on the rovers' own status messages, bounded by a generous failure timeout. The time from a STOP
reaching the broker's subscribers to each rover's status saying ``halt: stop`` is recorded (``stop_latencies_ms``
in the test's properties), not asserted: benchmarks/bench_command.py measures it.
"""

from __future__ import annotations

import os
import subprocess
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest

from edge.broker.credentials import credentials_path, ensure_credentials
from edge.commands import build_formation
from edge.messages import FORMATION_TOPIC, MAX_INT, dumps
from tests.support.command import (
    EDGE_IPS,
    Edge,
    SimRovers,
    arrival,
    cli_formation,
    formations,
    observer,
    retained_now,
    rover_reports,
    wait_reports,
)
from tests.support.dashboard import clean_env
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder

pytestmark = [pytest.mark.slow, pytest.mark.realtime]

ROVERS = ["red", "green", "blue"]
TOKEN = "e2e-dashboard-token"
EDGE_ID = f"e2e-{os.getpid() % 100_000}"  # ours, not another process's on a port it took (Edge.start checks)


@dataclass
class Deployment:
    """One broker setup: how the edge, the CLI, the rovers, the observer and a hostile client reach it."""

    name: str
    host: str
    port: int
    edge_url: str  # with the edge's credentials, if any: for `edge-ips formation`
    edge_args: list[str]  # for `edge-ips start`
    edge_env: dict[str, str]
    rover_args: list[str]
    user: str | None = None  # the observer's (and the insider's) credentials
    password: str | None = None

    def client(self, client_id: str) -> mqtt.Client:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id)
        if self.user is not None:
            client.username_pw_set(self.user, self.password)
        client.connect(self.host, self.port)
        client.loop_start()
        return client


def _run(args: list[str], cwd: Path, **env: str) -> str:
    done = subprocess.run([*EDGE_IPS, *args], cwd=cwd, env=clean_env(**env), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(params=["mosquitto", "embedded"])
def deployment(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Deployment]:
    if request.param == "embedded":
        port = free_port()
        # The logins `edge-ips start` generates in its state directory on first run (made here first, as a first
        # run would, so the rovers can be given theirs before the edge starts; the edge reuses them).
        state = tmp_path / "state"
        logins = ensure_credentials(state, ROVERS)
        edge = logins.edge
        yield Deployment(
            "embedded",
            "127.0.0.1",
            port,
            f"mqtt://{edge.username}:{edge.password}@127.0.0.1:{port}",
            ["--source", "sim"],  # no configuration: the embedded broker, closed to clients without a login
            clean_env(
                EDGE_IPS_BROKER__EMBEDDED_PORT=str(port),
                EDGE_IPS_DASHBOARD__TOKEN=TOKEN,
                EDGE_IPS_EDGE__ID=EDGE_ID,
                EDGE_IPS_EDGE__STATE_DIR=str(state),
            ),
            ["--broker", f"mqtt://127.0.0.1:{port}", "--credentials", str(credentials_path(state))],
            edge.username,  # the observer and the insider publishing a hostile retained line
            edge.password,
        )
        return
    ids = {"EDGE_IPS_EDGE__ID": EDGE_ID}  # the ACL names the edge's status topic
    conf = tmp_path / "broker"
    _run(["broker-config", "--out", str(conf), "--rovers", ",".join(ROVERS)], tmp_path, **ids)
    creds = tomllib.loads((conf / "credentials.toml").read_text())
    bundles = tmp_path / "bundles"
    for rover in ROVERS:  # what would be flashed, with the password broker-config made for the rover
        _run(
            ["flash", "--rover", rover, "--bundle", str(bundles / rover)],
            tmp_path,
            EDGE_IPS_WIFI_SSID="lab",
            EDGE_IPS_WIFI_PASSWORD="wifi-secret",
            EDGE_IPS_MQTT_PASSWORD=creds["rovers"][rover]["password"],
            EDGE_IPS_BROKER_HOST="192.168.1.50",  # the lab's address; --broker overrides it on this computer
        )
    edge_user, edge_password = creds["edge"]["username"], creds["edge"]["password"]
    # Its own free port, taken just before it starts (the listener line is the only one replaced).
    with Mosquitto(tmp_path / "mosquitto", conf_path=conf / "mosquitto.conf") as broker:
        url = f"mqtt://{edge_user}:{edge_password}@127.0.0.1:{broker.port}"
        yield Deployment(
            "mosquitto",
            broker.host,
            broker.port,
            url,
            ["--source", "sim", "--broker", url],
            clean_env(EDGE_IPS_DASHBOARD__TOKEN=TOKEN, **ids),
            # the rovers on the network listener (the loopback one takes the edge's login only)
            ["--broker", f"mqtt://127.0.0.1:{broker.ports[1883]}", "--config-dir", str(bundles)],
            edge_user,
            edge_password,
        )


def hostile_retained(d: Deployment) -> None:
    """A retained line at the top of the seq range (on an open broker anyone; behind the ACL an insider)."""
    client = d.client("hostile")
    payload = dumps(build_formation("line", ROVERS, seq=MAX_INT, spacing_cm=60.0))
    client.publish(FORMATION_TOPIC, payload, qos=1, retain=True).wait_for_publish(30)
    client.loop_stop()
    client.disconnect()


def last_formation(rec: MqttRecorder) -> dict[str, Any]:
    return formations(rec)[-1][1]


def test_every_rover_stops_through_restarts_hostile_seqs_and_two_writers(
    deployment: Deployment, tmp_path: Path, record_property: Callable[[str, object], None]
) -> None:
    d = deployment
    latencies: list[float] = []

    def stop_and_measure(send: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        """Send a STOP; every rover must report halt stop for it. Records the delay from the broker's delivery of
        the STOP (as the observer got it) to each rover's status."""
        after = time.time()
        sent = send()
        assert sent["kind"] == "stop"
        t_stop = arrival(rec, "stop", sent["seq"], after)
        reported = wait_reports(rec, ROVERS, "stop", sent["seq"], after)
        latencies.extend(1000 * (t - t_stop) for t in reported.values())
        return sent

    def drive(send: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        after = time.time()
        sent = send()
        wait_reports(rec, ROVERS, sent["kind"], sent["seq"], after)
        return sent

    def dashboard(kind: str) -> Callable[[], dict[str, Any]]:
        return lambda: edge.command(kind, TOKEN, ROVERS if kind != "stop" else [])

    def cli(kind: str) -> Callable[[], dict[str, Any]]:
        return lambda: cli_formation(kind, d.edge_url, tmp_path)

    rec = observer(d.host, d.port, d.user, d.password)
    edge = Edge(d.edge_args, d.edge_env, tmp_path)
    rovers = SimRovers(d.rover_args, tmp_path)
    try:
        edge.start()
        rec.start()
        rovers.start()
        # The appliance's own stop at start is the broker's retained command: every rover applies it.
        start_stop = last_formation_waited(rec)
        assert start_stop["kind"] == "stop"
        wait_reports(rec, ROVERS, "stop", start_stop["seq"], 0.0)
        line = drive(dashboard("line"))
        assert all(doc["halt"] != "stop" for reps in rover_reports(rec, 0.0).values() for _, doc in reps[-1:])

        # The edge crashes and comes back: every rover halts (the retained stop at start) until commanded again.
        edge.kill()
        before_restart = time.time()
        edge.start()
        restart_stop = formation_after(rec, before_restart)
        assert restart_stop["kind"] == "stop"
        if d.name == "mosquitto":  # the broker kept the line: the stop follows its seq
            assert restart_stop["seq"] == line["seq"] + 1
        wait_reports(rec, ROVERS, "stop", restart_stop["seq"], before_restart)

        drive(dashboard("line"))
        stop_and_measure(dashboard("stop"))
        drive(cli("line"))
        stop_and_measure(cli("stop"))

        # A hostile retained seq 999999999: rovers apply it (it is a command); the next STOP wraps to seq 1.
        for send in (dashboard("stop"), cli("stop")):
            after = time.time()
            hostile_retained(d)
            wait_reports(rec, ROVERS, "line", MAX_INT, after)
            assert stop_and_measure(send)["seq"] == 1

        # Two writers at once: the dashboard's STOP and the CLI's line. Every rover ends on the broker's retained
        # command; then one more STOP (a barrier: the broker delivers in order, so a rover reporting it has had both).
        drive(dashboard("line"))
        after = time.time()
        both = two_writers(lambda: edge.command("stop", TOKEN), cli("line"))
        retained = retained_now(d.host, d.port, d.user, d.password)
        assert (retained["kind"], retained["seq"]) in {(m["kind"], m["seq"]) for m in both}
        wait_reports(rec, ROVERS, retained["kind"], retained["seq"], after)
        barrier = stop_and_measure(dashboard("stop"))
        for rover, reports in rover_reports(rec, after).items():
            applied = [(doc["formation"], doc["seq"]) for _, doc in reports if doc["seq"] != barrier["seq"]]
            assert applied[-1] == (retained["kind"], retained["seq"]), f"{rover} ended on {applied}"
    finally:
        code = rovers.stop()
        edge.stop()
        rec.stop()
    assert code == 0, rovers.output()
    shown = rovers.output()
    assert all(f"{r}: online, halt stop, applies stop" in shown for r in ROVERS), shown
    assert "Traceback" not in shown
    record_property("stop_latencies_ms", sorted(round(x, 1) for x in latencies))
    record_property("two_writers_same_seq", len({m["seq"] for m in both}) == 1)
    assert len(latencies) == len(ROVERS) * 5


def last_formation_waited(rec: MqttRecorder) -> dict[str, Any]:
    assert rec.wait_for(lambda m: bool(formations(rec)), 60), "no formation retained"
    return last_formation(rec)


def formation_after(rec: MqttRecorder, after: float) -> dict[str, Any]:
    assert rec.wait_for(lambda m: bool(formations(rec, after)), 120), "no formation published after the restart"
    return formations(rec, after)[0][1]


def two_writers(*sends: Callable[[], dict[str, Any]]) -> list[dict[str, Any]]:
    """Run the writers at the same moment, each on its own thread; returns what each published."""
    start = threading.Barrier(len(sends))
    out: list[dict[str, Any]] = []
    errors: list[BaseException] = []

    def run(send: Callable[[], dict[str, Any]]) -> None:
        start.wait()
        try:
            out.append(send())
        except BaseException as exc:  # re-raised below, on the test's thread
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(s,)) for s in sends]
    for t in threads:
        t.start()
    for t in threads:
        t.join(300)
    if errors:
        raise errors[0]
    return out
