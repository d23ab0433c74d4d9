"""A budget of log lines: at most so many a minute; what is left out is counted and said in the next line written.

Whatever a client on the network can make the appliance log (a wrong token, a refused login, a malformed packet)
goes through one, so that a script cannot fill the journal, and no source of lines can use up another's.
"""

from __future__ import annotations

import threading


class LogBudget:
    """``per_minute`` lines per minute of the clock passed in (``now``, seconds); thread-safe."""

    def __init__(self, per_minute: int) -> None:
        self.per_minute = per_minute
        self._lock = threading.Lock()
        self._minute = -1.0
        self._used = 0
        self._skipped = 0

    def take(self, now: float) -> bool:
        """Whether a line may be written now; a line refused is counted (:meth:`left_out`)."""
        minute = now // 60.0
        with self._lock:
            if minute != self._minute:
                self._minute, self._used = minute, 0
            if self._used < self.per_minute:
                self._used += 1
                return True
            self._skipped += 1
            return False

    def left_out(self) -> int:
        """How many lines were left out since the last call (to say so in the line being written)."""
        with self._lock:
            skipped, self._skipped = self._skipped, 0
            return skipped

    def reset(self) -> None:
        """Start afresh (a service started anew)."""
        with self._lock:
            self._minute, self._used, self._skipped = -1.0, 0, 0
