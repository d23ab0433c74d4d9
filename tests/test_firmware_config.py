"""config.py's checks of the motor pins against the ESP8266's GPIOs (the same checks run on the board, in the
flash tool and in the host harness)."""

from __future__ import annotations

from typing import Any

import pytest

from edge.errors import ConfigError
from edge.rover_host import check_rover_config, firmware_modules
from firmware.harness.runner import rover_configs

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


def test_pwm_on_gpio16_is_refused_and_a_direction_pin_there_is_fine() -> None:
    with pytest.raises(ConfigError, match=r"key motors\.right\.pwm: GPIO 16 has no PWM on the ESP8266"):
        check_rover_config(with_motor("right", "pwm", 16))
    assert check_rover_config(with_motor("right", "dir2", 16))["motors"]["right"]["dir2"] == 16


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
