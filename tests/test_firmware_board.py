"""The rover on a board stand-in that behaves like an ESP8266 (firmware/harness/board.py): a reset runs boot.py and
main.py, a started machine.WDT resets the chip 3.2 s after its last feed whatever runs (the REPL does not feed it),
Ctrl-C ends the program, mpremote sessions take the time a serial link takes and are cut by a reset.

What must hold: an interrupted rover stays still until it is deliberately reset; the flash tool stops a running
rover before it copies anything and re-flashes it, even one running an older firmware with a hardware watchdog;
a rover that cannot start keeps its motors off, says why once, tells the broker when it can, and waits.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from edge import flashing
from firmware.harness.board import Board
from firmware.harness.runner import mpy_driver, rover_configs

PORT = "/dev/ttyUSB0"
# The design the issue found on the boards: a hardware watchdog fed by the loop (and nothing else).
OLD_MAIN = """import machine, time, app
m, r = app.start("config.json")
wdt = machine.WDT()
while True:
    r.step(time.ticks_ms())
    wdt.feed()
    time.sleep_ms(20)
"""


def rover_config() -> dict[str, Any]:
    cfg = rover_configs(["red"])[0]
    cfg["wifi"] = {"ssid": "lab", "password": "wifi-pw"}
    cfg["broker"] = {**cfg["broker"], "host": "10.0.0.2", "keepalive_s": 2}
    return cfg


@contextmanager
def flashed_board(tmp_path: Path, main: str | None = None, **board: Any) -> Iterator[tuple[Board, Path]]:
    """A board that was flashed with this firmware before (its files in place), the edge publishing poses and the
    retained formation; yields it with the bundle the flash tool would copy now."""
    bundle = tmp_path / "bundle"
    flashing.write_bundle(bundle, rover_config())
    root = tmp_path / "board"
    root.mkdir()
    for name in ("boot.py", "main.py", "config.json"):
        shutil.copyfile(bundle / name, root / name)
    if main is not None:
        (root / "main.py").write_text(main)
    stall = mpy_driver("stall")
    with Board(root, **board) as b:
        b.romfs = (bundle / "rom.img").read_bytes()
        b.broker.retained = stall.FORMATION
        b.clock.watchers.append(stall._Edge(b.broker, {}, 10**9))
        yield b, bundle


def mpremote(*args: str) -> list[str]:
    return ["python", "-m", "mpremote", "connect", PORT, *args]


def motor_pins() -> tuple[int, int]:
    cfg = rover_config()["motors"]
    return cfg["left"]["pwm"], cfg["right"]["pwm"]


@pytest.mark.slow
def test_a_rover_interrupted_by_an_mpremote_connection_stays_still_until_it_is_reset(tmp_path: Path) -> None:
    with flashed_board(tmp_path) as (board, _):
        board.power_on()
        board.run(3000)
        assert board.drove_after(0), board.console.getvalue()  # it was driving
        t_interrupt = board.clock.now
        result = board.mpremote(mpremote("exec", "print('hello')"))
        assert result.returncode == 0 and "hello" in result.stdout
        board.run(60_000)  # a minute at the REPL
        assert not board.drove_after(t_interrupt)
        assert board.resets == 0 and board.boots == 1
        assert board.dangling_timers == 0  # the watchdog's timer was disarmed with the loop
        assert board.output == ["KeyboardInterrupt"]
        statuses = [json.loads(p) for t, p in board.broker.published if t.endswith(b"/status")]
        assert statuses[-1]["state"] == "offline"  # and it said goodbye
        board.mpremote(mpremote("reset"))  # deliberately restarted: it drives again
        board.run(2000)
        assert board.drove_after(board.clock.now - 2000)


@pytest.mark.slow
def test_the_stand_in_resets_like_the_chip_when_the_firmware_started_a_hardware_watchdog(tmp_path: Path) -> None:
    # The failure the flash tool must survive: Ctrl-C stops the loop, nothing feeds the WDT, the chip resets 3.2 s
    # later, main.py runs again and the rover drives on the retained formation by itself.
    with flashed_board(tmp_path, main=OLD_MAIN) as (board, _):
        board.power_on()
        board.run(3000)
        t_interrupt = board.clock.now
        assert board.mpremote(mpremote("exec", "print('hello')")).returncode == 0
        board.run(10_000)
        assert board.resets == 1 and board.boots == 2
        assert board.drove_after(t_interrupt + 3200)
        # And a copy that takes longer than the watchdog is cut off by the reset (what re-flashing used to do).
        cut = board.mpremote(mpremote("romfs", "deploy", str(tmp_path / "bundle" / "rom.img"), "+", "reset"))
        assert cut.returncode != 0 and "reset" in cut.stderr


@pytest.mark.slow
@pytest.mark.parametrize("main", [None, OLD_MAIN], ids=["this firmware", "older firmware with machine.WDT"])
def test_the_flash_tool_stops_a_running_rover_and_reflashes_it(tmp_path: Path, main: str | None) -> None:
    with flashed_board(tmp_path, main=main) as (board, bundle):
        board.power_on()
        board.run(3000)
        assert board.drove_after(0)
        lines: list[str] = []
        flashing.flash(PORT, bundle, None, False, run=board.mpremote, echo=lines.append)
        assert lines[-1] == "ok: " + flashing.expected_answer(), lines
        assert any(line.startswith("stopped: the board runs MicroPython 1.28.0") for line in lines)
        files = sorted(p.name for p in board.root.iterdir())
        assert files == ["boot.py", "config.json", "main.py"]  # main.off and stale files gone
        assert (board.root / "main.py").read_bytes() == (bundle / "main.py").read_bytes()
        assert board.romfs == (bundle / "rom.img").read_bytes()
        t_flashed = board.clock.now
        board.run(3000)
        assert board.drove_after(t_flashed)  # live again on the new firmware
        assert board.dangling_timers == 0


@pytest.mark.slow
def test_the_flash_tool_refuses_a_board_with_another_micropython_and_leaves_it_stopped(tmp_path: Path) -> None:
    with flashed_board(tmp_path, version="1.24.1", romfs=False) as (board, bundle):
        board.power_on()
        board.run(2000)
        with pytest.raises(flashing.FlashError, match=r"runs MicroPython 1\.24\.1 without ROMFS.*main\.py is now"):
            flashing.flash(PORT, bundle, None, False, run=board.mpremote, echo=lambda s: None)
        t = board.clock.now
        board.run(10_000)
        assert not board.drove_after(t)
        assert sorted(p.name for p in board.root.iterdir()) == ["boot.py", "config.json", "main.off"]


@pytest.mark.slow
def test_a_rover_whose_config_is_broken_keeps_its_motors_off_says_why_once_and_waits(tmp_path: Path) -> None:
    with flashed_board(tmp_path) as (board, _):
        (board.root / "config.json").write_text('{"id": "red", "motors": ')
        board.power_on()
        board.run(30_000)
        left, right = motor_pins()
        assert board.pins[left] == 0 and board.pins[right] == 0  # boot.py drove them low
        assert not board.drove_after(-1)
        assert board.boots == 1  # no reboot loop
        lines = board.console.getvalue().splitlines()
        assert len([ln for ln in lines if ln.startswith("rover not started:")]) == 1, lines
        assert board.broker.connections == 0  # no broker known


@pytest.mark.slow
def test_a_rover_that_fails_after_reading_its_config_publishes_an_error_status(tmp_path: Path) -> None:
    with flashed_board(tmp_path, fail_pwm=True) as (board, _):
        board.power_on()
        board.run(5000)
        assert not board.drove_after(-1) and board.boots == 1
        statuses = [json.loads(p) for t, p in board.broker.published if t.endswith(b"/status")]
        assert statuses and statuses[0]["halt"] == "error" and statuses[0]["state"] == "online", statuses
        assert "PWM hardware fault" in board.console.getvalue()


@pytest.mark.slow
@pytest.mark.parametrize(
    "error",
    [ImportError("no module named 'app'"), MemoryError("memory allocation failed, allocating 1024 bytes")],
    ids=["app missing from ROMFS", "no heap to import app"],
)
def test_a_rover_that_cannot_import_its_program_keeps_its_motors_off_and_says_why_in_one_line(
    tmp_path: Path, error: Exception
) -> None:
    # main.py's own `import app` is the one failure app.run cannot catch: a ROMFS image without app.mpy (a copy cut
    # short), or no heap left to import it. It must end as every other failure before the loop does.
    with flashed_board(tmp_path, failing_imports={"app": error}) as (board, _):
        board.power_on()
        board.run(30_000)
        left, right = motor_pins()
        assert board.pins[left] == 0 and board.pins[right] == 0  # boot.py drove them low
        assert not board.drove_after(-1) and board.boots == 1  # no reboot loop
        assert board.output == []  # main.py ended without an exception: no traceback on the console
        lines = [ln for ln in board.console.getvalue().splitlines() if ln.strip()]
        assert lines == [f"rover not started: {error!r}"], lines


@pytest.mark.slow
def test_main_py_says_why_in_one_line_inside_micropython_when_app_cannot_be_imported(tmp_path: Path) -> None:
    # The same failure in MicroPython itself (harness/mpy/noapp.py): an app module that raises MemoryError on import.
    from firmware.harness.runner import run_micropython

    bundle = tmp_path / "bundle"
    flashing.write_bundle(bundle, rover_config())
    files = {name: (bundle / name).read_bytes() for name in ("boot.py", "main.py")}
    files["fail/app.py"] = b"raise MemoryError('memory allocation failed, allocating 1024 bytes')\n"
    pins = list(motor_pins())
    out = run_micropython(f"noapp.main('/input/data', '/input/data/fail', {pins!r})", files, standins=True)
    result = json.loads(out.splitlines()[-1])
    assert result["raised"] is None  # no traceback
    (line,) = result["printed"]  # one line (MicroPython's repr of an exception ends "...bytes',)")
    assert line.startswith("rover not started: MemoryError('memory allocation failed, allocating 1024 bytes'"), line
    assert result["outputs"] == [0, 0]  # boot.py left both PWM pins low


@pytest.mark.slow
def test_boot_py_drives_the_configs_pwm_pins_low_before_main_runs(tmp_path: Path) -> None:
    cfg = rover_config()
    cfg["motors"]["left"]["pwm"], cfg["motors"]["right"]["pwm"] = 14, 12
    source = flashing.boot_source(cfg)
    with flashed_board(tmp_path) as (board, _):
        (board.root / "boot.py").write_text(source)
        (board.root / "main.py").write_text("raise RuntimeError('main.py fails at once')\n")
        board.power_on()
        assert board.pins[14] == 0 and board.pins[12] == 0
        assert board.output == ["main.py raised RuntimeError('main.py fails at once')"]


@pytest.mark.slow
@pytest.mark.parametrize("duty", [600, 1023], ids=["part duty", "full duty"])
def test_a_wheel_left_turning_at_the_repl_stops_at_a_soft_reset_even_when_main_py_cannot_start(
    tmp_path: Path, duty: int
) -> None:
    # The wheel check of docs/firmware.md done by hand with m.stop() forgotten, then Ctrl-D with a broken config.json.
    # On the ESP8266 the PWM channel outlives the soft reset (esppwm.c's state is C statics, its timer interrupt
    # keeps pulsing the pin) and Pin(p, Pin.OUT, value=0) does not stop it: the pulse is back within a period. main.py
    # fails before it reaches the motors, so only boot.py can stop the wheel. At full duty no period ever clears the
    # pin, so ending the channel leaves it high: boot.py must drive it low after the channel is gone, not before.
    with flashed_board(tmp_path) as (board, _):
        (board.root / "config.json").write_text('{"id": "red", "motors": ')
        board.power_on()
        board.run(1000)
        left, right = motor_pins()
        by_hand = f"from machine import PWM, Pin; PWM(Pin({left}), freq=1000, duty={duty})"
        assert board.mpremote(mpremote("exec", by_hand)).returncode == 0
        assert board.outputs()[left] == duty  # turning at the REPL
        board.soft_reset()  # Ctrl-D
        board.run(30_000)
        assert board.outputs()[left] == 0 and board.outputs()[right] == 0
        assert board.boots == 2 and board.output == ["KeyboardInterrupt"]  # mpremote's Ctrl-C; main.py still waits
        lines = board.console.getvalue().splitlines()
        assert len([ln for ln in lines if ln.startswith("rover not started:")]) == 2, lines
