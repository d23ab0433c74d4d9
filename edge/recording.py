"""A recording of everything published: JSON lines, one message per line, rotated by size.

Each line is ``{"t":<publish time, Unix s>,"topic":"...","retain":false,"payload":<the payload>}`` where the
payload's exact bytes appear verbatim (our payloads are canonical JSON), so a run can be plotted and replayed
byte for byte. Files are ``<prefix>-<UTC start time>-<n>.jsonl`` in ``directory``; beyond ``max_bytes`` a new file
starts, beyond ``max_files`` the oldest is deleted.

Writing happens on the recorder's own thread behind a bounded queue: a slow SD card never slows the tracker.
If the queue is full the line is dropped and counted.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from edge.errors import ConfigError

log = logging.getLogger("edge.recording")

_STOP = object()


def record_line(t_s: float, topic: str, payload: bytes, retain: bool) -> bytes:
    """One JSON line; the payload is embedded as is when it is JSON, else as a string."""
    try:
        json.loads(payload)
        body = payload
    except ValueError:
        body = json.dumps(payload.decode("utf-8", "replace")).encode()
    head = f'{{"t":{t_s:.6f},"topic":{json.dumps(topic)},"retain":{"true" if retain else "false"},"payload":'
    return head.encode() + body + b"}\n"


class Recorder:
    """Records (topic, payload, retain) tuples handed to :meth:`record` (the publisher's tap)."""

    def __init__(
        self,
        directory: Path,
        *,
        max_bytes: int = 50_000_000,
        max_files: int = 20,
        prefix: str = "published",
        queue_size: int = 10_000,
    ) -> None:
        self.directory = Path(directory)
        self.max_bytes, self.max_files, self.prefix = max_bytes, max_files, prefix
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None
        self._file: IO[bytes] | None = None
        self._size = 0
        self._serial = 0
        self._stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        self.lines_written = 0
        self.lines_dropped = 0
        self.files_written: list[Path] = []

    def start(self) -> Recorder:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            probe = self.directory / ".edge-ips-write-test"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise ConfigError(f"recording.dir: {self.directory} is not writable ({exc.strerror})") from exc
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()
        return self

    def record(self, topic: str, payload: bytes, retain: bool) -> None:
        """Queue one published message (never blocks)."""
        try:
            self._queue.put_nowait((time.time(), topic, payload, retain))
        except queue.Full:
            self.lines_dropped += 1

    def _open_next(self) -> IO[bytes]:
        if self._file is not None:
            self._file.close()
        self._serial += 1
        path = self.directory / f"{self.prefix}-{self._stamp}-{self._serial:04d}.jsonl"
        self._file = path.open("ab")
        self._size = 0
        self.files_written.append(path)
        while len(self.files_written) > self.max_files:
            old = self.files_written.pop(0)
            old.unlink(missing_ok=True)
        return self._file

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                break
            line = record_line(*item)
            try:
                out = self._file
                if out is None or self._size + len(line) > self.max_bytes:
                    out = self._open_next()
                out.write(line)
                self._size += len(line)
                self.lines_written += 1
                if self._queue.empty():
                    out.flush()
            except OSError as exc:
                self.lines_dropped += 1
                log.error("recording: cannot write to %s: %s", self.directory, exc.strerror)
        if self._file is not None:
            self._file.flush()
            self._file.close()
            self._file = None

    def close(self, timeout_s: float = 10.0) -> None:
        """Write everything queued so far, then close the file."""
        if self._thread is None:
            return
        self._queue.put(_STOP)
        self._thread.join(timeout=timeout_s)
        self._thread = None
        log.info("recording flushed: %d lines in %s", self.lines_written, self.directory)


def read_recording(directory: Path, prefix: str = "published") -> Iterator[dict[str, Any]]:
    """Every recorded line of ``directory``, oldest file first."""
    for path in sorted(Path(directory).glob(f"{prefix}-*.jsonl")):
        with path.open("rb") as fh:
            for line in fh:
                yield json.loads(line)
