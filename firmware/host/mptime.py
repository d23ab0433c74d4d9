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
    return (_int(ticks) + _int(delta)) & (TICKS_PERIOD - 1)


def ticks_diff(a: int, b: int) -> int:
    return ((a - b + _HALF) & (TICKS_PERIOD - 1)) - _HALF


def _int(n: int) -> int:
    # The chip takes only ints here: time.sleep_ms(2.5) is a TypeError on the ESP8266, and must be one on the host.
    if type(n) is not int:
        raise TypeError("can't convert float to int")
    return n


def sleep_ms(ms: int) -> None:
    if _int(ms) > 0:
        time.sleep(ms / 1000)


def sleep_us(us: int) -> None:
    if _int(us) > 0:
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
