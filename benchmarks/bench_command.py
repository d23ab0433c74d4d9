#!/usr/bin/env python3
"""STOP to halt: how long after a STOP reaches the broker's subscribers each rover reports ``halt: stop``.

    .venv/bin/python benchmarks/bench_command.py                  # 30 STOPs through each broker
    .venv/bin/python benchmarks/bench_command.py --stops 100 --brokers embedded

What runs, all as separate processes, as in a lab: ``edge-ips start --source sim`` (the simulator's camera, so the
rovers get live poses) with its dashboard; a broker (a private Mosquitto with the users and ACL of
``edge-ips broker-config``, or the edge's embedded one); ``edge-ips sim rovers`` (red, green, blue: the flashed
firmware, each its own MQTT client with its own credentials). This script commands through the dashboard's HTTP API,
alternately ``line`` (waiting until every rover reports it) and STOP, and listens to the formation topic and the
rovers' statuses (rover status v2) on the broker.

Latency of one rover for one STOP = arrival of the rover's status saying ``halt: stop`` for that STOP's seq minus
arrival of the STOP itself, both at this script's subscriber (same client, same clock): the broker's delivery to the
rover, the rover's next 20 ms step, its status, the broker's delivery back. The dashboard's own work before it
publishes (connect, read the retained seq) is not counted: the clock starts when the command is on the broker.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

ROVERS = ("red", "green", "blue")
TOKEN = "bench-command-token"
EDGE_ID = "bench-command"  # checked on /api/state: the port answers from this edge, not another process's
EDGE_IPS = [sys.executable, "-m", "edge.cli"]
WAIT_S = 120.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Listener:
    """Formation messages and rover statuses with their arrival time (time.monotonic)."""

    def __init__(self, port: int, user: str | None, password: str | None) -> None:
        import paho.mqtt.client as mqtt

        from edge.messages import FORMATION_TOPIC, ROVER_STATUS_WILDCARD

        self.seen: list[tuple[float, str, dict[str, Any]]] = []
        self.cond = threading.Condition()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-command")
        if user is not None:
            self.client.username_pw_set(user, password)
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe([(FORMATION_TOPIC, 1), (ROVER_STATUS_WILDCARD, 1)])
        self.client.on_message = self._on_message
        self.client.connect_async("127.0.0.1", port)
        self.client.loop_start()

    def _on_message(self, client: Any, userdata: Any, message: Any) -> None:
        t = time.monotonic()
        if message.payload:
            with self.cond:
                self.seen.append((t, message.topic, json.loads(message.payload)))
                self.cond.notify_all()

    def wait(self, kind: str, seq: int, after: float) -> tuple[float, dict[str, float]]:
        """(arrival of the formation, {rover: arrival of its first status applying it}), all after ``after``."""

        def found() -> tuple[float | None, dict[str, float]]:
            t_cmd, reports = None, {}
            for t, topic, doc in self.seen:
                if t < after:
                    continue
                if topic.endswith("/formation") and (doc["kind"], doc["seq"]) == (kind, seq) and t_cmd is None:
                    t_cmd = t
                elif (
                    topic.endswith("/status")
                    and (doc["formation"], doc["seq"]) == (kind, seq)
                    and (kind != "stop" or doc["halt"] == "stop")
                    and doc["id"] not in reports
                ):
                    reports[doc["id"]] = t
            return t_cmd, reports

        with self.cond:
            if not self.cond.wait_for(lambda: found()[0] is not None and len(found()[1]) == len(ROVERS), WAIT_S):
                raise RuntimeError(f"rovers did not report {kind} (seq {seq}) within {WAIT_S:g} s")
            t_cmd, reports = found()
        assert t_cmd is not None
        return t_cmd, reports

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def command(http_port: int, kind: str) -> dict[str, Any]:
    """A formation as the page posts it; a STOP on the page's STOP route (``/api/stop``), as its button does."""
    body = json.dumps({"kind": kind, "ids": [] if kind == "stop" else list(ROVERS)}).encode()
    request = urllib.request.Request(
        f"http://127.0.0.1:{http_port}/api/{'stop' if kind == 'stop' else 'formation'}",
        data=body,
        headers={"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(request, timeout=30) as reply:
        return dict(json.loads(reply.read())["formation"])


def _wait_online(http_port: int, edge: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and edge.poll() is None:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/healthz", timeout=2):
                pass
            state_request = urllib.request.Request(
                f"http://127.0.0.1:{http_port}/api/state", headers={"Authorization": f"Bearer {TOKEN}"}
            )  # the page's state is behind the token when one is set
            with urllib.request.urlopen(state_request, timeout=2) as state:
                if json.loads(state.read())["edge_id"] == EDGE_ID and edge.poll() is None:
                    return
        except OSError:
            time.sleep(0.2)
    raise RuntimeError("the edge did not come online")


def _stop(proc: subprocess.Popen[bytes], sig: int = signal.SIGTERM) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run(kind: str, stops: int, workdir: Path) -> list[float]:
    """Latencies (ms), one per rover per STOP, through one broker."""
    from edge.broker import write_mosquitto_config

    port, http_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    env.update(PYTHONPATH=str(REPO), EDGE_IPS_DASHBOARD__TOKEN=TOKEN)
    procs: list[subprocess.Popen[bytes]] = []
    rover_args = ["--broker", f"mqtt://127.0.0.1:{port}"]
    user = password = None
    log = (workdir / f"{kind}.log").open("wb")
    try:
        if kind == "mosquitto":
            local_port = free_port()  # the edge's own clients share its login: they connect to the loopback listener
            files = write_mosquitto_config(
                workdir / "broker",
                rovers=list(ROVERS),
                edge_id=EDGE_ID,
                port=port,
                bind="127.0.0.1",
                local_port=local_port,
            )
            with files.conf.open("a") as conf:  # run as root, Mosquitto would drop to a user that cannot read tmp
                conf.write("log_dest stderr\n" + ("user root\n" if os.geteuid() == 0 else ""))
            procs.append(subprocess.Popen(["/usr/sbin/mosquitto", "-c", str(files.conf)], stdout=log, stderr=log))
            creds = tomllib.loads(files.credentials.read_text())
            user, password = creds["edge"]["username"], creds["edge"]["password"]
            edge_args = ["--broker", f"mqtt://{user}:{password}@127.0.0.1:{local_port}"]
            rover_args += ["--credentials", str(files.credentials)]
        else:
            from edge.broker.credentials import credentials_path, ensure_credentials

            # The logins `edge-ips start` makes in its state directory on the first run, made here first so the
            # rovers can be given theirs (as `edge-ips flash` provisions them from there).
            state = workdir / "state"
            ensure_credentials(state, list(ROVERS))
            env["EDGE_IPS_BROKER__EMBEDDED_PORT"] = str(port)
            env["EDGE_IPS_EDGE__STATE_DIR"] = str(state)
            rover_args += ["--credentials", str(credentials_path(state))]
            edge_args = []
        start = [*EDGE_IPS, "start", "--source", "sim", "--edge-id", EDGE_ID, "--http-port", str(http_port), *edge_args]
        edge = subprocess.Popen(start, cwd=workdir, env=env, stdout=log, stderr=log)
        procs.append(edge)
        _wait_online(http_port, edge)
        listener = Listener(port, user, password)
        rovers = subprocess.Popen([*EDGE_IPS, "sim", "rovers", *rover_args], cwd=workdir, env=env, stdout=log)
        procs.append(rovers)
        latencies: list[float] = []
        try:
            for k in range(stops):
                after = time.monotonic()
                line = command(http_port, "line")
                listener.wait("line", line["seq"], after)
                after = time.monotonic()
                stop = command(http_port, "stop")
                t_stop, reports = listener.wait("stop", stop["seq"], after)
                latencies += [1000.0 * (t - t_stop) for t in reports.values()]
                print(f"  STOP {k + 1}/{stops}: " + ", ".join(f"{(t - t_stop) * 1000:.1f}" for t in reports.values()))
        finally:
            listener.close()
        _stop(rovers, signal.SIGINT)
        return latencies
    except RuntimeError as exc:
        log.flush()
        tail = (workdir / f"{kind}.log").read_text(errors="replace").splitlines()[-15:]
        raise RuntimeError(f"{exc}; the processes' last lines:\n" + "\n".join(tail)) from exc
    finally:
        for proc in reversed(procs):
            _stop(proc)
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--stops", type=int, default=30, help="STOPs per broker (default 30)")
    parser.add_argument("--brokers", default="mosquitto,embedded", help="mosquitto, embedded or both")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-command-") as tmp:
        for kind in [b.strip() for b in args.brokers.split(",") if b.strip()]:
            print(f"{kind}: {args.stops} STOPs to {len(ROVERS)} rovers ...", flush=True)
            workdir = Path(tmp) / kind
            workdir.mkdir()
            ms = np.array(run(kind, args.stops, workdir))
            p50, p95, p99 = np.percentile(ms, [50, 95, 99])
            over = int((ms > 1000.0).sum())
            rows.append(f"| {kind} | {ms.size} | {p50:.1f} | {p95:.1f} | {p99:.1f} | {ms.max():.1f} | {over} |")
    cpu = f"{os.cpu_count()} cores {platform.machine()}"
    print(f"\nmachine: {platform.node()} ({cpu}), Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}")
    print("| broker | samples (rover x STOP) | p50 ms | p95 ms | p99 ms | max ms | over 1 s |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
