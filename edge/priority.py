"""Threads that only serve people yield the CPU to the tracker: on Linux each thread has its own nice value, so the
HTTP server's threads, the dashboard's JPEG encoder and event builder run at a lower priority than the tracker and
the capture thread. When the two cores are busy, the kernel serves the tracker first."""

from __future__ import annotations

import contextlib
import os
import threading

BACKGROUND_NICE = 10


def background_priority(nice: int = BACKGROUND_NICE) -> None:
    """Lower the calling thread's scheduling priority (Linux: per thread); elsewhere, or when refused, no change."""
    tid = threading.get_native_id()
    with contextlib.suppress(AttributeError, OSError):
        current = os.getpriority(os.PRIO_PROCESS, tid)
        if current < nice:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
