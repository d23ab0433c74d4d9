"""The rover never blocks beyond a bound, whatever the network does: the real app, link.py and the umqtt.simple of
MicroPython v1.28.0 (pinned) against a scripted broker that stalls at each point of a packet, in simulated time,
under CPython and inside MicroPython (firmware/harness/mpy/stall.py, firmware/harness/mpy/fakenet.py).

The stop bound: the motors are off at most 0.5 s after the last own pose that arrived whole. A Wi-Fi drop leaves the
rest of a packet (or anything after it) unsent and fills the send buffer; a silent broker takes the TCP connection
and says nothing; both runs must give the same answers to the millisecond.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import pytest

from firmware.harness.runner import STALL_CASES, run_stall, stall_config

STOP_BOUND_MS = 500
CUTS = ("boundary", "first byte", "remaining length", "topic length", "topic", "payload", "broker silent")
TIMEOUT_MS = int(stall_config()["broker"]["timeout_s"] * 1000)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], dict[str, Any]]:
    """Every case in both interpreters, once per module."""
    tmp = tmp_path_factory.mktemp("stall")
    out = {}
    for case in STALL_CASES:
        run_ms = 6000 if case == "wifi back" else 4000
        for interpreter in ("cpython", "micropython"):
            out[case, interpreter] = run_stall(case, interpreter, tmp, run_ms)
    return out


def both(runs: dict[tuple[str, str], dict[str, Any]], case: str) -> dict[str, Any]:
    """The case's summary, after checking that MicroPython and CPython agree on everything but the log's reprs."""
    cp, mp = runs[case, "cpython"], runs[case, "micropython"]
    keys = [k for k in cp if k != "log"]
    assert {k: cp[k] for k in keys} == {k: mp[k] for k in keys}, case
    return cp


@pytest.mark.slow
@pytest.mark.parametrize("case", CUTS)
def test_motors_stop_within_half_a_second_of_the_last_whole_pose_when_the_network_stalls(
    runs: dict[tuple[str, str], dict[str, Any]], case: str
) -> None:
    r = both(runs, case)
    assert r["first_drive_ms"] is not None and r["first_drive_ms"] < r["stall_ms"]  # it was driving
    assert r["off_ms"] is not None and r["last_pose_ms"] is not None
    assert r["off_ms"] - r["last_pose_ms"] <= STOP_BOUND_MS, r
    assert r["drove_after_stall"] == [] and not r["on_at_end"]  # and stays stopped
    assert r["drops"] >= 1 and r["halt"] == "disconnected"  # the dead link was noticed (1.5 keepalives)


@pytest.mark.slow
def test_a_send_buffer_that_stays_full_stops_the_motors_before_the_write_waits(
    runs: dict[tuple[str, str], dict[str, Any]],
) -> None:
    r = both(runs, "send buffer full")
    assert r["off_ms"] - r["last_pose_ms"] <= STOP_BOUND_MS and r["waits"] >= 1
    assert r["drove_after_stall"] == [] and r["drops"] == 1
    downs = [int(line.split()[0]) for line in r["log"] if "broker link down: OSError(110)" in line]
    assert downs and downs[0] - r["off_ms"] <= TIMEOUT_MS  # the wait gave up after timeout_s


@pytest.mark.slow
@pytest.mark.parametrize("case", ["broker never answers", "no SUBACK"])
def test_a_broker_that_takes_the_connection_but_never_answers_cannot_hold_the_loop(
    runs: dict[tuple[str, str], dict[str, Any]], case: str
) -> None:
    r = both(runs, case)
    assert r["first_drive_ms"] is None and not r["on_at_end"]
    downs = [int(line.split()[0]) for line in r["log"] if "broker link down" in line]
    assert len(downs) >= 3  # it keeps trying, each try bounded
    gaps = [b - a for a, b in itertools.pairwise(downs)]
    assert max(gaps) <= TIMEOUT_MS + 8000 + 20, gaps  # timeout_s, the longest backoff, a loop period


@pytest.mark.slow
def test_a_retained_message_too_long_to_keep_is_dropped_unread_and_the_link_stays_up(
    runs: dict[tuple[str, str], dict[str, Any]],
) -> None:
    r = both(runs, "oversize retained")
    assert r["dropped_packets"] == 1 and r["connects"] == 1 and r["drops"] == 0  # no reconnect loop
    assert r["first_drive_ms"] is not None and r["first_drive_ms"] > r["stall_ms"]  # the next formation works
    assert any("dropped a packet of 6036 bytes" in line for line in r["log"])


@pytest.mark.slow
def test_after_a_wifi_drop_mid_packet_the_rover_stops_then_reconnects_and_drives_again(
    runs: dict[tuple[str, str], dict[str, Any]],
) -> None:
    r = both(runs, "wifi back")
    assert r["off_ms"] - r["last_pose_ms"] <= STOP_BOUND_MS
    assert r["connects"] == 2 and r["drops"] == 1
    assert r["drove_after_stall"] and r["drove_after_stall"][0] > r["off_ms"]


@pytest.mark.slow
def test_the_backlog_after_an_outage_is_not_driven_on(runs: dict[tuple[str, str], dict[str, Any]]) -> None:
    """1.5 s without a byte, the TCP connection kept: then everything sent meanwhile at once (PINGRESP included), in
    order. The rover stopped within the bound, and drove again only on a pose younger than stale_ms."""
    r = both(runs, "backlog")
    assert r["off_ms"] - r["last_pose_ms"] <= STOP_BOUND_MS
    assert r["connects"] == 1 and r["drops"] == 0  # the link rode the outage out
    release = r["stall_ms"] + 1500
    assert r["drove_after_stall"] and r["drove_after_stall"][0] > release
    stale_ms = stall_config()["control"]["stale_ms"]
    assert r["rejoin_pose_age_ms"] <= stale_ms  # young: the backlog was 0-1.5 s old


@pytest.mark.slow
def test_ctrl_c_stops_the_motors_and_the_watchdog_for_good(runs: dict[tuple[str, str], dict[str, Any]]) -> None:
    r = both(runs, "ctrl-c")
    assert r["interrupted_ms"] == r["stall_ms"] and r["off_ms"] - r["interrupted_ms"] <= 1  # sampled each ms
    assert r["drove_after_stall"] == [] and not r["on_at_end"]  # three seconds at the REPL: still
    assert r["timers_armed"] == 0 and r["disconnects"] == 1
    assert '"state":"offline"' in r["published"][-1]


def test_the_stall_runs_use_the_pinned_umqtt(tmp_path: Path) -> None:
    import hashlib

    from firmware.harness.runner import HOST

    digest = hashlib.sha256((HOST / "umqtt" / "simple.py").read_bytes()).hexdigest()
    assert digest == "0792c0bd6d9219c8180a9ee7dae3d7c15fafe53e0605fa30839b1033fa4a189c"  # umqtt.simple 1.7.0


@pytest.mark.slow
def test_a_second_ctrl_c_inside_the_stop_leaves_the_motors_off_and_the_timer_disarmed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C pressed twice: the port raises the second KeyboardInterrupt at the next bytecode, so it lands inside
    app.stop wherever the first one's stop has got to. With the watchdog disarmed first and the motors stopped
    after, a second Ctrl-C right after the disarm left the rover driving at the REPL, with nothing left to stop it.
    Each case in CPython and MicroPython (firmware/harness/mpy/interrupt.py)."""
    import json

    from firmware.harness.runner import mpy_driver, run_micropython

    cfg = json.dumps(stall_config()).encode()
    (tmp_path / "config.json").write_bytes(cfg)
    capsys.readouterr()
    mpy_driver("interrupt").main(str(tmp_path / "config.json"))
    in_cpython = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    in_mpy = [
        json.loads(line)
        for line in run_micropython(
            "interrupt.main('/input/data/config.json')", {"config.json": cfg}, True
        ).splitlines()
    ]
    assert in_cpython == in_mpy
    assert [row[0] for row in in_cpython] == ["motors.stop", "watchdog.stop", "timer.deinit", "left.set"]
    for where, interrupted, left, right, timers in in_cpython:
        assert interrupted and (left, right, timers) == (0, 0, 0), where


@pytest.mark.slow
def test_ctrl_c_between_arming_the_watchdog_and_the_loop_leaves_its_timer_disarmed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C can land at any bytecode of app.run: right after the watchdog's timer was armed and before the try whose
    finally disarms it, the timer stayed armed at the REPL (and a soft reset frees the callback it fires into).
    Interrupted right after the start and right after the timer's init, in CPython and MicroPython
    (firmware/harness/mpy/interrupt.py ``run``)."""
    import json

    from firmware.harness.runner import mpy_driver, run_micropython

    cfg = json.dumps(stall_config()).encode()
    (tmp_path / "config.json").write_bytes(cfg)
    capsys.readouterr()
    mpy_driver("interrupt").run(str(tmp_path / "config.json"))
    in_cpython = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    out = run_micropython("interrupt.run('/input/data/config.json')", {"config.json": cfg}, True)
    in_mpy = [json.loads(line) for line in out.splitlines()]
    assert in_cpython == in_mpy
    assert [row[0] for row in in_cpython] == ["app.start", "Timer.init"]
    for where, interrupted, timers, duty in in_cpython:
        assert interrupted and (timers, duty) == (0, 0), where
