"""A recording of everything published: JSON lines, one message per line, rotated by size.

Each line is ``{"t":<publish time, Unix s>,"topic":"...","retain":false,"payload":<the payload>}`` where the
payload's exact bytes appear verbatim (our payloads are canonical JSON), so a run can be plotted and replayed
byte for byte.

Files are ``<prefix>-<seq>-<UTC time>.jsonl`` in ``directory``. ``seq`` counts on from the files already there, so
the order holds across restarts even on a board whose clock is not set yet. Beyond ``max_bytes`` a new file
starts; beyond ``max_files`` the oldest files of the directory are deleted, whichever process wrote them (files
named ``<prefix>-<UTC time>-<n>.jsonl`` by earlier versions count too, as the oldest).

Writing happens on the recorder's own thread behind a bounded queue: a slow SD card never slows the tracker. If
the queue is full the line is dropped and counted. Lines reach the file whole or not at all: each batch is one
``os.write``, and when the disk fills in the middle of a line the file is cut back to the last whole line, so
``lines_written`` is what the files hold. A full disk (or one that fails) pauses the recording with one warning:
lines are dropped and counted, a write is tried again every ``retry_s``, and the recording resumes (saying how
many lines were lost) when one succeeds. A file that cannot grow any more (``EFBIG``: FAT32's 4 GiB, a file size
limit) is closed and the next one started.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import queue
import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from edge.errors import ConfigError

log = logging.getLogger("edge.recording")

_STOP = object()
BATCH_BYTES = 64 * 1024  # lines queued meanwhile are written together, up to this much
WARN_EVERY_S = 300.0  # a disk that fills and frees again says so at most this often


def record_line(t_s: float, topic: str, payload: bytes, retain: bool) -> bytes:
    """One JSON line; the payload is embedded as is when it is JSON, else as a string."""
    try:
        json.loads(payload)
        body = payload
    except ValueError:
        body = json.dumps(payload.decode("utf-8", "replace")).encode()
    head = f'{{"t":{t_s:.6f},"topic":{json.dumps(topic)},"retain":{"true" if retain else "false"},"payload":'
    return head.encode() + body + b"}\n"


def _order(prefix: str) -> tuple[re.Pattern[str], re.Pattern[str]]:
    p = re.escape(prefix)
    return (
        re.compile(rf"^{p}-(\d{{6,}})-\d{{8}}T\d{{6}}Z\.jsonl$"),  # <prefix>-<seq>-<time>.jsonl
        re.compile(rf"^{p}-(\d{{8}}T\d{{6}}Z)-(\d+)\.jsonl$"),  # earlier versions: <prefix>-<time>-<n>.jsonl
    )


def recording_files(directory: Path, prefix: str = "published") -> list[Path]:
    """The recording files of ``directory``, oldest first (other files are never touched)."""
    current, earlier = _order(prefix)
    keyed: list[tuple[tuple[int, str, int], Path]] = []
    for path in Path(directory).glob(f"{prefix}-*.jsonl"):
        if m := current.match(path.name):
            keyed.append(((1, "", int(m.group(1))), path))
        elif m := earlier.match(path.name):
            keyed.append(((0, m.group(1), int(m.group(2))), path))
    return [path for _, path in sorted(keyed)]


def _sequence(path: Path, prefix: str) -> int:
    m = _order(prefix)[0].match(path.name)
    return int(m.group(1)) if m else 0


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
        retry_s: float = 5.0,
    ) -> None:
        self.directory = Path(directory)
        self.max_bytes, self.max_files, self.prefix = max_bytes, max_files, prefix
        self.retry_s = retry_s
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None
        self._fd: int | None = None
        self._size = 0
        self._next_seq = 1
        self._retry_mono = 0.0
        self._warned_mono = -float("inf")
        self._pause_said = False
        self._dropped_lock = threading.Lock()
        self._dropped_queue = 0  # by the producers (queue full)
        self._dropped_disk = 0  # by the writer (paused or failed)
        self._dropped_at_pause = 0
        self.files: list[Path] = []  # the directory's recording files, oldest first
        self.paused = False
        self.lines_written = 0

    @property
    def lines_dropped(self) -> int:
        return self._dropped_queue + self._dropped_disk

    def start(self) -> Recorder:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            probe = self.directory / ".edge-ips-write-test"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise ConfigError(f"recording.dir: {self.directory} is not writable ({exc.strerror})") from exc
        self.files = recording_files(self.directory, self.prefix)
        self._next_seq = 1 + max((_sequence(p, self.prefix) for p in self.files), default=0)
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()
        return self

    def record(self, topic: str, payload: bytes, retain: bool) -> None:
        """Queue one published message (never blocks)."""
        try:
            self._queue.put_nowait((time.time(), topic, payload, retain))
        except queue.Full:
            with self._dropped_lock:
                self._dropped_queue += 1

    # -- the writer thread ----------------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            held: Any = None  # a stop or flush that ended the last batch: handled after writing it
            while True:
                item = held if held is not None else self._queue.get()
                held = None
                if item is _STOP:
                    break
                if isinstance(item, threading.Event):  # flush(): everything queued before it is written
                    item.set()
                    continue
                batch = [record_line(*item)]
                size = len(batch[0])
                while size < BATCH_BYTES:
                    try:
                        item = self._queue.get_nowait()
                    except queue.Empty:
                        break
                    if item is _STOP or isinstance(item, threading.Event):
                        held = item
                        break
                    batch.append(record_line(*item))
                    size += len(batch[-1])
                self._write(batch)
        except Exception as exc:  # never a traceback from this thread: say it in one line
            log.error("recording stopped: %s: %s", type(exc).__name__, exc)
        finally:
            self._close_file()

    def _write(self, lines: list[bytes]) -> None:
        if self.paused and time.monotonic() < self._retry_mono:
            self._dropped_disk += len(lines)
            return
        while lines:
            try:
                fd = self._file_for(len(lines[0]))
                fits, room = 0, self.max_bytes - self._size
                while fits < len(lines) and (fits == 0 or len(lines[fits]) <= room):
                    room -= len(lines[fits])
                    fits += 1
                self._write_whole(fd, lines[:fits])
                lines = lines[fits:]
            except _Torn as torn:
                lines = lines[torn.whole :]
                if torn.error.errno == errno.EFBIG and (torn.whole > 0 or self._size > 0):
                    self._close_file()  # this file cannot grow: the next one can
                    continue
                self._pause(torn.error, len(lines))
                return
            except OSError as exc:  # opening a file
                self._pause(exc, len(lines))
                return
        if self.paused:
            self.paused = False
            lost = self._dropped_disk - self._dropped_at_pause
            level = logging.INFO if self._pause_said else logging.DEBUG
            log.log(level, "recording resumed in %s; %d lines dropped while it could not write", self.directory, lost)

    def _write_whole(self, fd: int, lines: list[bytes]) -> None:
        """Write ``lines`` and count them; raises :class:`_Torn` (after cutting a partly written line off and
        counting the whole ones) when the file could not take them all."""
        data = memoryview(b"".join(lines))
        done = 0
        try:
            while done < len(data):
                n = os.write(fd, data[done:])
                if n <= 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                done += n
        except OSError as exc:
            whole, end = 0, 0
            for line in lines:
                if end + len(line) > done:
                    break
                end += len(line)
                whole += 1
            if done > end:
                try:
                    os.ftruncate(fd, self._size + end)  # the file ends on a whole line again
                except OSError as cut:
                    log.warning("recording: cannot cut a torn line off (%s); readers will skip it", cut.strerror)
            self._size += end
            self.lines_written += whole
            raise _Torn(whole, exc) from exc
        self._size += done
        self.lines_written += len(lines)

    def _file_for(self, line_bytes: int) -> int:
        if self._fd is not None and (self._size == 0 or self._size + line_bytes <= self.max_bytes):
            return self._fd
        self._close_file()
        while True:
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            path = self.directory / f"{self.prefix}-{self._next_seq:06d}-{stamp}.jsonl"
            self._next_seq += 1
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_CLOEXEC, 0o644)
            except FileExistsError:  # another recorder in the same directory: take the next number
                continue
            break
        self._fd, self._size = fd, 0
        self.files.append(path)
        while len(self.files) > self.max_files:
            oldest = self.files.pop(0)
            try:
                oldest.unlink(missing_ok=True)
            except OSError as exc:
                log.warning("recording: cannot delete %s (%s)", oldest, exc.strerror)
        return fd

    def _pause(self, exc: OSError, dropped: int) -> None:
        self._dropped_disk += dropped
        now = time.monotonic()
        self._retry_mono = now + self.retry_s
        if self.paused:
            return
        self.paused = True
        self._dropped_at_pause = self._dropped_disk - dropped
        self._pause_said = now - self._warned_mono >= WARN_EVERY_S
        if self._pause_said:
            self._warned_mono = now
            log.warning(
                "recording paused: cannot write to %s (%s); lines are dropped and counted until it can "
                "(tried again every %g s)",
                self.directory,
                exc.strerror or exc,
                self.retry_s,
            )

    def _close_file(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.close(fd)
            except OSError as exc:
                log.warning("recording: closing a file failed (%s)", exc.strerror)

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until everything queued so far has been written (or dropped); False on timeout."""
        done = threading.Event()
        try:
            self._queue.put(done, timeout=timeout_s)
        except queue.Full:
            return False
        return done.wait(timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Write everything queued so far, then close the file."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        try:
            self._queue.put(_STOP, timeout=timeout_s)
        except queue.Full:
            log.warning("recording: the writer is stuck (%d lines queued); not waiting for it", self._queue.qsize())
            return
        thread.join(timeout=timeout_s)
        if thread.is_alive():
            log.warning("recording: the writer did not finish within %g s", timeout_s)
        log.info(
            "recording flushed: %d lines in %s (%d dropped)", self.lines_written, self.directory, self.lines_dropped
        )


class _Torn(Exception):
    def __init__(self, whole: int, error: OSError) -> None:
        super().__init__(error)
        self.whole, self.error = whole, error


def read_recording(directory: Path, prefix: str = "published") -> Iterator[dict[str, Any]]:
    """Every recorded line of ``directory``, oldest file first. A torn last line (the recorder stopped in the middle
    of writing it) is skipped with a warning, as is any line that is not a JSON record."""
    for path in recording_files(directory, prefix):
        with path.open("rb") as fh:
            line = fh.readline()
            lineno = 1
            while line:
                following = fh.readline()
                try:
                    if not line.endswith(b"\n"):
                        raise ValueError("no end of line")
                    record = json.loads(line)
                    if not isinstance(record, dict):
                        raise ValueError("not a record")
                except ValueError:
                    if following:
                        log.warning("recording: %s:%d is not a JSON record; skipped", path, lineno)
                    else:
                        log.warning(
                            "recording: %s ends in a torn line (%d bytes: the recorder stopped while writing it); "
                            "skipped",
                            path,
                            len(line),
                        )
                else:
                    yield record
                line, lineno = following, lineno + 1
