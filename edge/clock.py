"""Time as the appliance reads it: a monotonic clock for intervals and ages, a wall clock for what goes on the wire.

The runtime, the capture thread and the status take a :class:`Clock` instead of calling ``time`` themselves, so a
test (or a simulation) can move time on by hand and see a rover go missing or a camera stall at once, without
waiting for it.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    """``monotonic()``: seconds for intervals, never going back. ``wall()``: Unix seconds, for timestamps."""

    def monotonic(self) -> float: ...

    def wall(self) -> float: ...


class SystemClock:
    """The computer's clocks (``time.monotonic``, ``time.time``)."""

    def monotonic(self) -> float:
        return time.monotonic()

    def wall(self) -> float:
        return time.time()


SYSTEM_CLOCK = SystemClock()


class ManualClock:
    """A clock that moves only when :meth:`advance` is called; both readings move together. Thread-safe."""

    def __init__(self, monotonic_s: float = 1000.0, wall_s: float = 1.7e9) -> None:
        self._monotonic_s = monotonic_s
        self._wall_s = wall_s
        self._lock = threading.Lock()

    def monotonic(self) -> float:
        with self._lock:
            return self._monotonic_s

    def wall(self) -> float:
        with self._lock:
            return self._wall_s

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError(f"a clock does not go back ({seconds} s)")
        with self._lock:
            self._monotonic_s += seconds
            self._wall_s += seconds
