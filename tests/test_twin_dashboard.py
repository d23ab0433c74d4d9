"""The dashboard's twin parts without a lab process: the simulator panel's routes on a real HTTP server over an
in-memory lab (who may scatter and cause faults, what a fault request may say, the edge's own faults), the token
made on the first start, and how a killed edge starts again."""

from __future__ import annotations

import json
import os
import stat
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from edge.config import EdgeConfig
from edge.dashboard.first_token import dashboard_token, token_path
from edge.dashboard.sim_panel import EdgeFaults, SimPanel, attach_sim_panel, without_after_kill
from edge.errors import ConfigError, EdgeIpsError, SimulationError
from edge.httpserver import HttpServer
from tests.support.dashboard import call

TOKEN = "twin-panel-token"
AUTH = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}


class MemoryLab:
    """A lab's controls in memory: what was asked, and a status to answer."""

    def __init__(self) -> None:
        self.asked: list[tuple[Any, ...]] = []

    def scatter(self) -> dict[str, Any]:
        self.asked.append(("scatter",))
        return {"red": [100.0, 200.0]}

    def fault(self, kind: str, seconds: float, rover: str | None = None) -> str:
        if kind == "wifi" and rover != "red":
            raise SimulationError(f"no rover {rover!r} in the lab (rovers: red)")
        self.asked.append(("fault", kind, seconds, rover))
        return f"{kind} for {seconds:g} s"

    def note(self, label: str) -> None:
        self.asked.append(("note", label))

    def status(self, after: int = 0) -> dict[str, Any]:
        return {
            "ok": True,
            "rovers": [{"id": "red", "switched_on": True, "connected": True, "moving": False, "speed_cm_s": 0.0}],
            "faults": [{"kind": "camera", "rover": None, "label": "camera hung for 3 s", "left_s": 2.5}],
            "events": [{"n": 7, "t": 1.0, "who": "lab", "text": "fault: camera hung for 3 s"}][after:],
            "camera": {"frames": 10, "skipped": 0, "readers": 1, "stalled": True},
            "cameras": [{"name": "cam1", "frames": 10, "skipped": 0, "readers": 1, "stalled": True}],
        }


class Broker:
    """The embedded broker as far as a restart goes: it says when it stopped and started."""

    def __init__(self) -> None:
        self.calls: list[str] = []
        self.started = threading.Event()

    def stop(self, timeout_s: float = 10.0) -> None:
        self.calls.append("stop")

    def start(self, timeout_s: float = 10.0) -> Broker:
        self.calls.append("start")
        self.started.set()
        return self


class LabSource:
    def __init__(self, controls: MemoryLab) -> None:
        self.controls = controls


@pytest.fixture
def served() -> Iterator[tuple[HttpServer, MemoryLab, Broker]]:
    config = EdgeConfig.model_validate({"http": {"host": "127.0.0.1", "port": 0}, "dashboard": {"token": TOKEN}})
    http = HttpServer.from_config(config.http, config.dashboard).start()
    lab, broker = MemoryLab(), Broker()
    attach_sim_panel(http, LabSource(lab), broker=broker, restart_argv=None, enabled=True)
    try:
        yield http, lab, broker
    finally:
        http.stop()


def _post(http: HttpServer, path: str, body: Any, headers: dict[str, str] | None = None) -> tuple[int, Any]:
    reply = call(http.port, "POST", path, json.dumps(body).encode(), AUTH if headers is None else headers)
    return reply.status, reply.json()


def test_the_panel_shows_the_labs_rovers_faults_and_events_to_a_viewer_with_the_token(served: Any) -> None:
    http, _, _ = served
    assert call(http.port, "GET", "/api/sim").status == 401
    reply = call(http.port, "GET", "/api/sim", headers=AUTH)
    info = reply.json()
    assert reply.status == 200
    assert info["offered"] == ["wifi", "camera", "broker"]  # no edge kill: not started by `edge-ips start`
    assert info["active"][0]["label"] == "camera hung for 3 s"
    assert info["rovers"][0]["id"] == "red" and info["events"][0]["n"] == 7
    assert [c["name"] for c in info["cameras"]] == ["cam1"] and info["camera"]["stalled"]
    assert call(http.port, "GET", "/api/sim?after=1", headers=AUTH).json()["events"] == []


@pytest.mark.parametrize(
    ("headers", "status"),
    [({}, 401), ({"Authorization": "Bearer wrong-token-here"}, 401), (AUTH, 200)],
)
def test_scatter_needs_the_control_token(served: Any, headers: dict[str, str], status: int) -> None:
    http, lab, _ = served
    code, body = _post(http, "/api/sim/scatter", {}, headers)
    assert code == status
    assert lab.asked == ([("scatter",)] if status == 200 else [])
    if status == 200:
        assert body["placed"] == {"red": [100.0, 200.0]}


@pytest.mark.parametrize(
    ("body", "status", "error"),
    [
        ({"kind": "flood", "seconds": 1}, 400, "kind"),
        ({"kind": "wifi", "seconds": 0}, 400, "seconds"),
        ({"kind": "wifi", "seconds": 301}, 400, "seconds"),
        ({"kind": "camera", "seconds": 1, "extra": 1}, 400, "extra"),
        ("not an object", 400, "fault request"),
        ({"kind": "wifi", "seconds": 1, "rover": "blue"}, 409, "no rover 'blue'"),
        ({"kind": "edge", "seconds": 3}, 409, "not started by `edge-ips start`"),
    ],
)
def test_a_fault_request_is_checked_before_anything_happens(served: Any, body: Any, status: int, error: str) -> None:
    http, lab, broker = served
    code, reply = _post(http, "/api/sim/fault", body)
    assert (code, error in reply["error"]) == (status, True), reply
    assert lab.asked == [] and broker.calls == []


@pytest.mark.slow
def test_lab_faults_go_to_the_lab_and_a_broker_restart_is_announced_to_it_first(served: Any) -> None:
    http, lab, broker = served
    assert _post(http, "/api/sim/fault", {"kind": "wifi", "seconds": 2, "rover": "red"}) == (
        200,
        {"ok": True, "done": "wifi for 2 s"},
    )
    code, reply = _post(http, "/api/sim/fault", {"kind": "broker", "seconds": 0.5})
    assert (code, reply["done"]) == (200, "broker restart (0.5 s down)")
    assert broker.started.wait(30)
    assert broker.calls == ["stop", "start"]
    assert lab.asked == [("fault", "wifi", 2.0, "red"), ("note", "broker restart (0.5 s down)")]


def test_without_a_control_token_the_simulator_controls_answer_403() -> None:
    config = EdgeConfig.model_validate({"http": {"host": "127.0.0.1", "port": 0}})
    http = HttpServer.from_config(config.http, config.dashboard).start()
    try:
        lab = MemoryLab()
        attach_sim_panel(http, LabSource(lab), broker=None, restart_argv=None, enabled=False)
        code, reply = _post(http, "/api/sim/scatter", {}, {})
        assert (code, "no dashboard token" in reply["error"]) == (403, True)
        assert call(http.port, "GET", "/api/sim").json()["controls_enabled"] is False
        assert lab.asked == []
    finally:
        http.stop()


def test_a_source_without_lab_controls_gets_no_panel() -> None:
    config = EdgeConfig.model_validate({"http": {"host": "127.0.0.1", "port": 0}})
    http = HttpServer.from_config(config.http, config.dashboard).start()
    try:
        assert attach_sim_panel(http, object(), broker=None, restart_argv=None, enabled=True) is None
        assert call(http.port, "GET", "/api/sim").status == 404
    finally:
        http.stop()


@pytest.mark.parametrize(
    ("kind", "seconds", "broker", "argv", "why"),
    [
        ("broker", 1.0, None, None, "the broker is an external one"),
        ("edge", 3.0, None, None, "not started by `edge-ips start`"),
        ("edge", 25.0, None, ["-m", "edge.cli", "start"], "at most 20 s"),
    ],
)
def test_the_edges_own_faults_say_why_they_cannot_happen(
    kind: str, seconds: float, broker: Any, argv: list[str] | None, why: str
) -> None:
    with pytest.raises(EdgeIpsError, match=why):
        EdgeFaults(broker, argv).check(kind, seconds)
    assert SimPanel(MemoryLab(), EdgeFaults(Broker(), ["start"]), enabled=True).faults.offered() == ["broker", "edge"]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["-m", "edge.cli", "start"], ["-m", "edge.cli", "start"]),
        (["-m", "edge.cli", "start", "--after-kill", "3"], ["-m", "edge.cli", "start"]),
        (["x", "start", "--after-kill=3", "--http-port", "1"], ["x", "start", "--http-port", "1"]),
    ],
)
def test_a_killed_edge_starts_again_with_its_own_command_line(argv: list[str], expected: list[str]) -> None:
    assert without_after_kill(argv) == expected


def test_the_first_start_makes_a_private_token_and_later_starts_reuse_it(tmp_path: Path) -> None:
    state = tmp_path / "state"
    token, made = dashboard_token(state)
    assert made and len(token) >= 32
    assert stat.S_IMODE(os.stat(token_path(state)).st_mode) == 0o600
    assert stat.S_IMODE(os.stat(state).st_mode) == 0o700
    assert dashboard_token(state) == (token, False)


@pytest.mark.parametrize("content", ["short", "two words here", ""])
def test_a_token_file_that_is_not_a_token_is_a_one_line_error(tmp_path: Path, content: str) -> None:
    token_path(tmp_path).write_text(content)
    with pytest.raises(ConfigError, match="not a dashboard token"):
        dashboard_token(tmp_path)
