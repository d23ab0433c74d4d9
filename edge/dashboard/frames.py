"""The dashboard's camera view: the newest frame as JPEG, encoded on its own thread, rate-capped, downscaled, once
per new frame whatever the number of viewers, and only while someone is looking.

The encoder thread sleeps until a page asks for a frame and goes back to sleep ``idle_after_s`` after the last
request. The HTTP server's loop waits for a frame with :meth:`FrameEncoder.wait_frame` (no thread per request:
the encoder hands each new JPEG to the waiting loops). In the appliance it is woken as the tracker finishes a
frame (``wait_next``) and encodes that frame (``runtime.last_frame``), so the work falls in the gap before the
next frame (2.5 ms of tracking, then ~30 ms idle at 30 fps) instead of beside the tracker; it only reads that
reference, so the tracker never waits for it.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.metrics import LatencyWindow
from edge.priority import background_priority
from edge.tracking import Frame

POLL_S = 0.005  # without ``wait_next``: how often the encoder looks for a newer frame


@dataclass(frozen=True)
class EncodedFrame:
    """One JPEG of the camera view. ``seq`` counts encodings; ``index`` is the source's frame number."""

    seq: int
    index: int
    t_capture_s: float
    width_px: int
    height_px: int
    jpeg: bytes


def encode_jpeg(image: NDArray[np.uint8], *, max_width_px: int, quality: int) -> tuple[bytes, int, int]:
    """(H, W, 3) BGR -> JPEG bytes and the encoded (width, height), downscaled to at most ``max_width_px`` wide."""
    h, w = image.shape[:2]
    out = image
    if w > max_width_px:
        size = (max_width_px, max(1, round(h * max_width_px / w)))
        # Bilinear is enough down to half size and 4x cheaper than INTER_AREA at 0.75 (0.8 ms against 3.9 ms for
        # 1280 -> 960 here, and OpenCV spreads a resize over every core, the tracker's included); further down,
        # INTER_AREA avoids aliasing.
        interpolation = cv2.INTER_LINEAR if max_width_px * 2 >= w else cv2.INTER_AREA
        out = np.asarray(cv2.resize(image, size, interpolation=interpolation), dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes(), int(out.shape[1]), int(out.shape[0])


class FrameEncoder:
    """Encodes the newest frame at most ``max_fps`` times a second while frames are being asked for."""

    def __init__(
        self,
        peek: Callable[[], Frame | None],
        *,
        max_fps: float = 10.0,
        quality: int = 70,
        max_width_px: int = 960,
        idle_after_s: float = 3.0,
        wait_next: Callable[[float], None] | None = None,
    ) -> None:
        self._peek = peek
        self._wait_next = wait_next
        self.min_interval_s = 1.0 / max_fps
        self.quality = quality
        self.max_width_px = max_width_px
        self.idle_after_s = idle_after_s
        self._cond = threading.Condition()
        self._latest: EncodedFrame | None = None
        self._last_request = -float("inf")
        self._closed = False
        self._thread: threading.Thread | None = None
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Future[EncodedFrame | None]]] = []
        self.encode_time = LatencyWindow(1000)
        self.encoded = 0

    @property
    def active(self) -> bool:
        """True while someone asked for a frame in the last ``idle_after_s``."""
        return time.monotonic() - self._last_request < self.idle_after_s

    def _wanted(self) -> bool:
        return self._closed or time.monotonic() - self._last_request < self.idle_after_s

    def _run(self) -> None:
        background_priority()
        last_frame: Frame | None = None
        next_allowed = 0.0
        while True:
            with self._cond:
                self._cond.wait_for(self._wanted)  # asleep while nobody watches
                if self._closed:
                    return
            if self._wait_next is not None:
                self._wait_next(0.25)  # returns as the tracker finishes a frame: encode in the gap after it
            else:
                time.sleep(POLL_S)
            if time.monotonic() < next_allowed:
                continue
            frame = self._peek()
            if frame is None or frame is last_frame:
                continue
            t0 = time.monotonic()
            jpeg, w, h = encode_jpeg(frame.image, max_width_px=self.max_width_px, quality=self.quality)
            t1 = time.monotonic()
            self.encode_time.add(t1 - t0)
            last_frame = frame
            next_allowed = t0 + 0.85 * self.min_interval_s  # frames come on the camera's clock: 10 of 30 fps, not 7.5
            with self._cond:
                seq = self._latest.seq + 1 if self._latest is not None else 1
                latest = self._latest = EncodedFrame(seq, frame.index, frame.t_capture_s, w, h, jpeg)
                self.encoded += 1
                self._cond.notify_all()
                waiters, self._waiters = self._waiters, []
            for loop, future in waiters:
                loop.call_soon_threadsafe(_resolve, future, latest)

    def _asked(self) -> None:
        """Someone wants a frame: wake (or start) the encoder. Call with ``_cond`` held."""
        self._last_request = time.monotonic()
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="dashboard-jpeg", daemon=True)
            self._thread.start()
        self._cond.notify_all()

    async def wait_frame(self, timeout_s: float = 2.0) -> EncodedFrame | None:
        """On an asyncio loop: the next JPEG encoded from now, waiting up to ``timeout_s``; on timeout the newest
        one there is (None if none was ever encoded)."""
        future: asyncio.Future[EncodedFrame | None] = asyncio.get_running_loop().create_future()
        with self._cond:
            if self._closed:
                return self._latest
            self._waiters.append((asyncio.get_running_loop(), future))
            self._asked()
        try:
            return await asyncio.wait_for(future, timeout_s)
        except TimeoutError:
            with self._cond:
                self._waiters = [(lp, f) for lp, f in self._waiters if f is not future]
                return self._latest

    def next_frame(self, after_seq: int | None = None, timeout_s: float = 2.0) -> EncodedFrame | None:
        """A JPEG newer than ``after_seq`` (default: newer than the one held now), waiting up to ``timeout_s``;
        on timeout the newest one there is (None if none was ever encoded)."""
        with self._cond:
            if self._closed:
                return self._latest
            self._asked()
            floor = after_seq if after_seq is not None else (self._latest.seq if self._latest is not None else 0)
            self._cond.wait_for(
                lambda: self._closed or (self._latest is not None and self._latest.seq > floor), timeout=timeout_s
            )
            return self._latest

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
            waiters, self._waiters = self._waiters, []
        for loop, future in waiters:
            loop.call_soon_threadsafe(_resolve, future, self._latest)
        if self._thread is not None:
            self._thread.join(timeout=2.0)


def _resolve(future: asyncio.Future[EncodedFrame | None], frame: EncodedFrame | None) -> None:
    if not future.done():  # the waiter may have timed out meanwhile
        future.set_result(frame)
