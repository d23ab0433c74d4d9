"""Helpers for the dashboard's tests: HTTP calls to a running appliance, an SSE reader, Debian's chromium through
Playwright, a formation subscriber, and ``edge-ips start`` as a subprocess."""

from __future__ import annotations

import http.client
import json
import os
import queue
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from benchmarks._common import CHROMIUM, CHROMIUM_ARGS, ReadyLine
from edge.messages import FORMATION_TOPIC
from tests.conftest import REPO
from tests.support.mosquitto import free_port
from tests.support.runtime import stop_process


@dataclass
class Reply:
    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)


def call(port: int, method: str, path: str, body: bytes | None = None, headers: dict[str, str] | None = None) -> Reply:
    """One HTTP request to 127.0.0.1:port."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        resp = conn.getresponse()
        return Reply(resp.status, {k.lower(): v for k, v in resp.getheaders()}, resp.read())
    finally:
        conn.close()


def read_events(
    port: int, wanted: dict[str, int], limit: int = 2000, headers: dict[str, str] | None = None
) -> dict[str, list[Any]]:
    """Read ``/api/events`` until at least ``wanted[name]`` events of each name arrived; returns them by name."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    got: dict[str, list[Any]] = {name: [] for name in wanted}
    try:
        conn.request("GET", "/api/events", headers=headers or {})
        resp = conn.getresponse()
        assert resp.status == 200
        assert resp.getheader("Content-Type", "").startswith("text/event-stream")
        name = ""
        for _ in range(limit):
            line = resp.fp.readline().decode().rstrip("\n")
            if line.startswith("event: "):
                name = line[len("event: ") :]
            elif line.startswith("data: "):
                got.setdefault(name, []).append(json.loads(line[len("data: ") :]))
            if all(len(got[n]) >= k for n, k in wanted.items()):
                return got
        raise AssertionError(f"not enough events in {limit} lines: { ({n: len(v) for n, v in got.items()}) }")
    finally:
        conn.close()


class FormationSubscriber:
    """A separate paho client on the formation topic: every message it receives, in order."""

    def __init__(self, host: str, port: int) -> None:
        self.messages: queue.Queue[tuple[bytes, bool]] = queue.Queue()
        self.subscribed = queue.Queue[bool]()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"test-formation-{os.getpid()}")
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe(FORMATION_TOPIC, qos=1)
        self.client.on_subscribe = lambda c, u, mid, rcs, p: self.subscribed.put(True)
        self.client.on_message = lambda c, u, m: self.messages.put((bytes(m.payload), bool(m.retain)))
        self.client.connect(host, port)
        self.client.loop_start()
        self.subscribed.get(timeout=10)

    def next(self, timeout_s: float = 20.0) -> tuple[dict[str, Any], bool]:
        payload, retained = self.messages.get(timeout=timeout_s)
        return json.loads(payload), retained

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return {**env, "PYTHONPATH": str(REPO), **extra}


@dataclass
class EdgeProcess:
    proc: subprocess.Popen[bytes]
    http_port: int
    log_path: Path
    output: ReadyLine | None = None  # the thread copying the process's output into log_path

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}/"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_log(self, text: str, timeout_s: float = 30.0) -> str:
        """The log once it holds ``text``: what the edge wrote reaches the file through a copying thread, so a
        line logged before a response may not be there yet when the response arrives (``timeout_s``: a guard)."""
        if self.output is not None:
            self.output.wait_copied(lambda: text in self.log(), timeout_s)
        return self.log()


class PortTaken(AssertionError):
    """Another process took the free port chosen for the dashboard before the appliance bound it."""


def edge_online(line: bytes) -> bool:
    """The appliance's readiness line: the runtime says it is online (its first status, once every route is up)."""
    return line.rstrip().endswith(b"edge.runtime: status online")


@contextmanager
def edge_start(args: list[str], workdir: Path, env: dict[str, str]) -> Iterator[EdgeProcess]:
    """``edge-ips start ARGS --http-port <free>`` in a subprocess, once it says it is online; stopped with SIGTERM
    (the service's way). :class:`PortTaken` when another process took the port first."""
    port = free_port()
    workdir.mkdir(parents=True, exist_ok=True)
    log_path = workdir / "edge.log"
    proc = subprocess.Popen(
        [sys.executable, "-m", "edge.cli", "start", "--http-port", str(port), *args],
        cwd=workdir,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    assert proc.stdout is not None
    output = ReadyLine(proc.stdout, log_path, edge_online)
    edge = EdgeProcess(proc, port, log_path, output)
    try:
        if not output.wait(120):
            proc.wait(10)  # the output ended: the process is exiting
            if "already in use" in edge.log():
                raise PortTaken(edge.log())
            raise AssertionError(f"edge-ips start did not come online:\n{edge.log()}")
        yield edge
    finally:
        stop_process(proc)


@contextmanager
def chromium() -> Iterator[Any]:
    """Debian's chromium (headless) driven by Playwright; no browser download involved. One per test module:
    Playwright's sync API allows one running instance per thread."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()
