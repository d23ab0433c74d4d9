"""MicroPython's ``time.ticks_*`` and ``sleep_ms`` for CPython: ``install()`` adds the missing ones to ``time``.

Only names CPython's ``time`` lacks are added, and none is replaced, so nothing else in the process changes. Ticks
wrap at 2**30 like the ESP8266's.
"""

from __future__ import annotations

import time

TICKS_PERIOD = 1 << 30
_HALF = TICKS_PERIOD // 2


def ticks_ms() -> int:
    return int(time.monotonic() * 1000) & (TICKS_PERIOD - 1)


def ticks_us() -> int:
    return int(time.monotonic() * 1_000_000) & (TICKS_PERIOD - 1)


def ticks_add(ticks: int, delta: int) -> int:
    return (ticks + delta) & (TICKS_PERIOD - 1)


def ticks_diff(a: int, b: int) -> int:
    return ((a - b + _HALF) & (TICKS_PERIOD - 1)) - _HALF


def sleep_ms(ms: int) -> None:
    if ms > 0:
        time.sleep(ms / 1000)


def sleep_us(us: int) -> None:
    if us > 0:
        time.sleep(us / 1_000_000)


def install() -> None:
    for name, fn in (
        ("ticks_ms", ticks_ms),
        ("ticks_us", ticks_us),
        ("ticks_add", ticks_add),
        ("ticks_diff", ticks_diff),
        ("sleep_ms", sleep_ms),
        ("sleep_us", sleep_us),
    ):
        if not hasattr(time, name):
            setattr(time, name, fn)
