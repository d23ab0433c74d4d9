"""The capture side of a live source: a newest-frame slot and the thread that fills it, reopening the source.

Live capture runs on a :class:`CaptureThread` that writes into a :class:`FrameSlot` holding only the newest frame:
the tracker always takes the newest frame, an older one it did not get to is overwritten (and counted), so no
queue can grow and latency cannot creep up. When a camera vanishes or a stream stalls, the capture thread closes
the source and reopens it with exponential backoff.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import replace

from edge.clock import SYSTEM_CLOCK, Clock
from edge.errors import SourceError
from edge.sources import FrameSource, SourceInfo
from edge.tracking import Frame

log = logging.getLogger("edge.sources")


class FrameSlot:
    """Holds only the newest frame. ``put`` overwrites (counting a frame nobody took); ``take`` waits for a new one.

    One writer (the capture thread) and one consumer (the tracker); ``peek`` lets others (a dashboard) look at the
    newest frame without taking it.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._fresh = False
        self._closed = False
        self.put_count = 0
        self.overwritten = 0

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self._fresh:
                self.overwritten += 1
            self._frame, self._fresh = frame, True
            self.put_count += 1
            self._cond.notify_all()

    def take(self, timeout_s: float | None = None) -> Frame | None:
        """The newest frame not yet taken, waiting up to ``timeout_s``; None on timeout or when closed."""
        with self._cond:
            self._cond.wait_for(lambda: self._fresh or self._closed, timeout=timeout_s)
            if not self._fresh:
                return None
            self._fresh = False
            return self._frame

    def peek(self) -> Frame | None:
        with self._cond:
            return self._frame

    def close(self) -> None:
        """No more frames will come: wake the consumer."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


class CaptureThread(threading.Thread):
    """Reads an already opened source into a :class:`FrameSlot`; reopens it with backoff when it fails.

    ``state``: ``ok`` while frames come, ``missing`` while the source cannot be (re)opened or read, ``stopped``
    after a finite source ended or on stop. A stall (an open source that delivers nothing) is judged by the
    reader of :attr:`last_frame_mono` against its own timeout: a blocked read cannot report itself.

    Every frame has the size the source had when it was first opened (``info``), the size the calibration and the
    tracker were set up for. A camera that comes back from a reopen at another size (a UVC camera re-enumerated
    with its default mode, another program that changed the format, a stream restarted at another resolution) is
    not passed on: the thread says so once (``problem`` holds the reason while it lasts), and keeps reopening the
    source, which asks for the configured size again each time, until it delivers the size it was calibrated for.
    """

    def __init__(
        self,
        source: FrameSource,
        slot: FrameSlot,
        stop: threading.Event,
        *,
        info: SourceInfo,
        reopen_min_s: float = 0.5,
        reopen_max_s: float = 8.0,
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        super().__init__(name="capture", daemon=True)
        self.clock = clock
        self.source, self.slot, self.stop_event = source, slot, stop
        self.info = info
        self.reopen_min_s, self.reopen_max_s = reopen_min_s, max(reopen_max_s, reopen_min_s)
        self.state = "ok"
        self.problem = ""
        self.expected_size = (info.width_px, info.height_px)
        self.frames = 0
        self.failures = 0
        self.reopens = 0
        self.ended = False
        self.error: BaseException | None = None
        self.last_frame_mono = self.clock.monotonic()
        self._last_index = -1
        self._offset = 0

    def _renumber(self, frame: Frame) -> Frame:
        # Indices stay strictly increasing across reopens (a reopened camera counts from 0 again).
        if frame.index + self._offset <= self._last_index:
            self._offset = self._last_index + 1 - frame.index
        self._last_index = frame.index + self._offset
        return frame if self._offset == 0 else replace(frame, index=self._last_index)

    def _size_problem(self, width_px: int, height_px: int) -> str:
        if (width_px, height_px) == self.expected_size:
            return ""
        w, h = self.expected_size
        return (
            f"the source delivers {width_px}x{height_px} frames but was calibrated at {w}x{h}; waiting for it at "
            f"{w}x{h} (or calibrate at {width_px}x{height_px} and set camera.width and camera.height)"
        )

    def _reopen(self, reason: str) -> None:
        self.failures += 1
        self.state = "missing"
        if not self.problem:
            log.warning("source lost: %s; reopening with backoff", reason)
        self.source.close()
        delay = self.reopen_min_s
        while not self.stop_event.wait(delay):
            next_delay = min(delay * 2, self.reopen_max_s)
            try:
                info = self.source.open()
            except SourceError as exc:
                log.info("reopen failed, next try in %.1f s: %s", next_delay, exc)
                delay = next_delay
                continue
            problem = self._size_problem(info.width_px, info.height_px)
            if problem:
                self.source.close()
                if problem != self.problem:  # said once, not at every attempt
                    log.warning("%s: %s", info.description, problem)
                self.problem = problem
                delay = next_delay
                continue
            self.info = info
            self.problem = ""
            self.reopens += 1
            self.last_frame_mono = self.clock.monotonic()
            self.state = "ok"
            log.info("source reopened: %s", self.info.description)
            return

    def run(self) -> None:
        try:
            while not self.stop_event.is_set():
                try:
                    frame = self.source.read()
                except SourceError as exc:
                    self._reopen(str(exc))
                    continue
                if frame is None:
                    log.info("source ended: %s", self.info.description)
                    self.ended = True
                    break
                height_px, width_px = frame.image.shape[:2]
                problem = self._size_problem(width_px, height_px)
                if problem:  # a stream that changed its resolution without a reconnect
                    log.warning("%s: %s", self.info.description, problem)
                    self.problem = problem
                    self._reopen(problem)
                    continue
                self.slot.put(self._renumber(frame))
                self.frames += 1
                self.last_frame_mono = frame.t_mono_s
                self.state = "ok"
        except Exception as exc:  # not a source failure: a bug; the runtime stops and reports it
            self.error = exc
            log.error("capture thread failed: %s: %s", type(exc).__name__, exc)
        finally:
            self.state = "stopped"
            self.source.close()
            self.slot.close()
