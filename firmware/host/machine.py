"""Host stand-in for MicroPython's ``machine``: the pins, PWM and watchdog the firmware touches, recording state.

Every instance remembers what the firmware did to it (level, duty, frequency, feeds), so a test or the closed-loop
simulation can read the motor commands back. Instances are independent: several rovers in one process each get
their own pins.
"""

from __future__ import annotations

from typing import Any

_freq_hz = 80_000_000


def freq(hz: int | None = None) -> int | None:
    """CPU frequency (the ESP8266 runs at 80 or 160 MHz)."""
    global _freq_hz
    if hz is None:
        return _freq_hz
    if hz not in (80_000_000, 160_000_000):
        raise ValueError(f"frequency {hz} Hz not supported by the ESP8266")
    _freq_hz = hz
    return None


class Pin:
    IN = 0
    OUT = 1
    OPEN_DRAIN = 2
    PULL_UP = 1

    def __init__(self, id: int, mode: int = -1, pull: int = -1, *, value: int | None = None) -> None:
        if not 0 <= id <= 16:
            raise ValueError(f"invalid pin {id}")
        self.id = id
        self.mode = mode
        self.level = 0 if value is None else int(bool(value))

    def value(self, v: Any = None) -> int | None:
        if v is None:
            return self.level
        self.level = int(bool(v))
        return None

    def on(self) -> None:
        self.level = 1

    def off(self) -> None:
        self.level = 0

    def __repr__(self) -> str:
        return f"Pin({self.id})"


class PWM:
    MAX_DUTY = 1023

    def __init__(self, pin: Pin, freq: int = 1000, duty: int | None = None, duty_u16: int | None = None) -> None:
        if not 1 <= freq <= 1000:
            raise ValueError(f"PWM frequency {freq} Hz outside 1..1000 (ESP8266)")
        if duty is None and duty_u16 is None:
            raise ValueError("PWM created without a duty: the ESP8266 would start it at its previous or default duty")
        self.pin = pin
        self.frequency = freq
        self.duty_value = 0
        self.changes = 0
        self.duty(duty if duty is not None else (duty_u16 or 0) * 1023 // 65535)

    def duty(self, d: int | None = None) -> int | None:
        if d is None:
            return self.duty_value
        if not isinstance(d, int) or not 0 <= d <= self.MAX_DUTY:
            raise ValueError(f"PWM duty {d!r} outside 0..1023")
        self.duty_value = d
        self.changes += 1
        return None

    def freq(self, f: int | None = None) -> int | None:
        if f is None:
            return self.frequency
        self.frequency = f
        return None

    def deinit(self) -> None:
        self.duty_value = 0


class WDT:
    """Counts feeds; never resets the host."""

    def __init__(self, id: int = 0, timeout: int = 5000) -> None:
        self.timeout_ms = timeout
        self.feeds = 0

    def feed(self) -> None:
        self.feeds += 1


def reset() -> None:
    raise SystemExit("machine.reset() on the host")


def unique_id() -> bytes:
    return b"\x00\x00\x00\x00"
