"""The pages' event streams on the HTTP server's loop, fed by one thread whatever the number of pages.

:class:`edge.dashboard.events.EventHub` builds each event once and hands it to its viewers through a blocking
iterator. Here one thread (``dashboard-fanout``, running only while a page is connected) is the hub's single viewer
and passes every chunk to the loop, which copies it to each page's queue; a page that does not keep up loses its
oldest chunks (at most ``queue_size`` kept), nobody else waits for it. The HTTP server needs no thread per page.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterator


class _Page:
    __slots__ = ("chunks", "dropped", "ended", "loop", "ready")

    def __init__(self, loop: asyncio.AbstractEventLoop, size: int) -> None:
        self.loop = loop
        self.chunks: deque[bytes] = deque(maxlen=size)
        self.ready = asyncio.Event()
        self.ended = False
        self.dropped = 0

    def put(self, chunk: bytes | None) -> None:  # on the page's loop
        if chunk is None:
            self.ended = True
        else:
            if len(self.chunks) == self.chunks.maxlen:
                self.dropped += 1
            self.chunks.append(chunk)
        self.ready.set()


class EventFanout:
    """``open_stream()``: a new blocking iterator of chunks from the hub (its first chunk, the stream's opening, is
    skipped: each page gets its own from :meth:`stream`)."""

    def __init__(self, open_stream: Callable[[], Iterator[bytes]], queue_size: int = 32) -> None:
        self._open_stream = open_stream
        self._queue_size = queue_size
        self._lock = threading.Lock()
        self._pages: set[_Page] = set()
        self._thread: threading.Thread | None = None
        self._closed = False

    @property
    def pages(self) -> int:
        with self._lock:
            return len(self._pages)

    async def stream(self, opening: bytes) -> AsyncIterator[bytes]:
        """One page's event stream: ``opening`` at once, then every chunk the hub sends, until the hub closes or
        the page goes away."""
        page = _Page(asyncio.get_running_loop(), self._queue_size)
        with self._lock:
            if self._closed:
                return
            self._pages.add(page)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="dashboard-fanout", daemon=True)
                self._thread.start()
        try:
            yield opening
            while True:
                await page.ready.wait()
                page.ready.clear()
                if page.chunks:
                    chunks = b"".join(page.chunks)
                    page.chunks.clear()
                    yield chunks
                if page.ended:
                    return
        finally:
            with self._lock:
                self._pages.discard(page)

    def _run(self) -> None:
        source = self._open_stream()
        try:
            next(source, None)  # the hub's opening: each page has its own
            for chunk in source:
                with self._lock:
                    pages = list(self._pages)
                    if not pages:  # the last page went away: let the hub sleep
                        self._thread = None
                        return
                for page in pages:
                    _post(page, chunk)
            with self._lock:  # the hub closed: end every page's stream
                self._closed = True
                pages = list(self._pages)
                self._thread = None
            for page in pages:
                _post(page, None)
        finally:
            close = getattr(source, "close", None)
            if close is not None:
                close()  # the hub forgets this viewer now


def _post(page: _Page, chunk: bytes | None) -> None:
    with contextlib.suppress(RuntimeError):  # the server's loop has closed (stopping): nobody reads this page
        page.loop.call_soon_threadsafe(page.put, chunk)
