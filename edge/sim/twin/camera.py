"""The twin's camera: the world rendered as it moves, at the camera's frame rate, in real time.

Frame ``k`` is exposed at ``t0 + k / fps`` (the world as it is then) and handed over ``latency_s`` later: a USB
webcam's readout, transfer and decoding, which happen whatever the edge does. Rendering is part of that delay; a
frame whose rendering took longer goes out late, and the frames whose exposure time passed meanwhile are never
taken, as a camera that cannot keep up drops frames. Each reader has its own newest-frame slot, so a slow reader
misses frames instead of falling behind. :meth:`TwinCamera.stall` stops the pictures (a camera that hangs: the
stream stays open, nothing comes).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from edge.capture import FrameSlot
from edge.sim.world import WorldState
from edge.tracking import Frame

Render = Callable[[WorldState, int], NDArray[np.uint8]]


class TwinCamera:
    """Renders ``state()`` with ``render(state, frame number)`` every ``1 / fps`` s for its readers (see above)."""

    def __init__(
        self,
        render: Render,
        state: Callable[[], WorldState],
        *,
        fps: float,
        latency_s: float,
        clock: Callable[[], float] = time.monotonic,
        name: str = "cam1",
    ) -> None:
        self.name = name
        self.render = render
        self.state = state
        self.fps = fps
        self.latency_s = latency_s
        self.clock = clock
        self.frames = 0  # handed over
        self.skipped = 0  # exposure times that passed while a frame was being made
        self._readers: list[FrameSlot] = []
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._stalled_until = -1.0
        self._thread: threading.Thread | None = None

    # -- readers ----------------------------------------------------------------------------------------------------
    def attach(self) -> FrameSlot:
        with self._lock:
            slot = FrameSlot()
            self._readers.append(slot)
            self._wake.notify_all()
            return slot

    def detach(self, slot: FrameSlot) -> None:
        with self._lock:
            if slot in self._readers:
                self._readers.remove(slot)
        slot.close()

    @property
    def readers(self) -> int:
        with self._lock:
            return len(self._readers)

    def stall(self, seconds: float) -> None:
        """No pictures for ``seconds`` from now."""
        with self._lock:
            self._stalled_until = max(self._stalled_until, self.clock() + seconds)

    @property
    def stalled(self) -> bool:
        with self._lock:
            return self.clock() < self._stalled_until

    # -- the camera's own loop --------------------------------------------------------------------------------------
    def start(self, stop: threading.Event) -> TwinCamera:
        self._thread = threading.Thread(target=self._run, args=(stop,), name=f"twin-{self.name}", daemon=True)
        self._thread.start()
        return self

    def _run(self, stop: threading.Event) -> None:
        t0 = self.clock()
        k = 0
        while not stop.is_set():
            exposure = t0 + k / self.fps
            if stop.wait(max(0.0, exposure - self.clock())):
                break
            with self._lock:  # nobody watching: nothing rendered (the world goes on)
                if not self._readers:
                    self._wake.wait(0.5)
            if self.readers and not self.stalled:
                image = self.render(self.state(), k)
                if stop.wait(max(0.0, exposure + self.latency_s - self.clock())):
                    break
                self._hand_over(image, k)
            due = math.floor((self.clock() - t0) * self.fps)
            if due > k + 1:
                self.skipped += due - k - 1
            k = max(k + 1, due)

    def _hand_over(self, image: NDArray[np.uint8], number: int) -> None:
        frame = Frame(image=image, index=number, t_capture_s=time.time(), t_mono_s=self.clock())
        with self._lock:
            readers = list(self._readers)
        for slot in readers:
            slot.put(frame)
        self.frames += 1

    @property
    def thread(self) -> threading.Thread | None:
        return self._thread

    def join(self, timeout_s: float = 5.0) -> None:
        if self._thread is not None:
            self._thread.join(timeout_s)
