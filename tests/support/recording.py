"""A recorder on a disk that fills up, run in a child process (the limits must not reach the test runner):

    python -m tests.support.recording disk-full DIR   # DIR: a tiny tmpfs (see tiny_tmpfs_command)
    python -m tests.support.recording fsize DIR       # under RLIMIT_FSIZE: no file may grow beyond 16 KiB

Prints one JSON object with what the recorder counted, what the files hold and what it logged.
"""

from __future__ import annotations

import json
import logging
import resource
import signal
import sys
from pathlib import Path
from typing import Any

from edge.recording import Recorder, read_recording, recording_files

TMPFS_BYTES = 64 * 1024
FILLER_BYTES = 44 * 1024  # what else is on the disk: the recorder gets the rest (about 20 KiB)
FSIZE_BYTES = 16 * 1024


def tiny_tmpfs_command(directory: Path, *child: str) -> list[str]:
    """``child`` run in a mount namespace of its own with a ``TMPFS_BYTES`` tmpfs mounted on ``directory``."""
    script = f'mount -t tmpfs -o size={TMPFS_BYTES} tmpfs "$1" && shift && exec "$@"'
    return ["unshare", "--map-root-user", "--mount", "sh", "-c", script, "sh", str(directory), *child]


def _payload(k: int) -> bytes:
    return json.dumps({"v": 1, "k": k, "pad": "x" * 150}, separators=(",", ":")).encode()


def _files(directory: Path) -> dict[str, Any]:
    files = recording_files(directory)
    return {
        "files": len(files),
        "largest_file_bytes": max((p.stat().st_size for p in files), default=0),
        "all_end_whole": all(p.read_bytes().endswith(b"\n") for p in files if p.stat().st_size),
        "lines_in_files": sum(p.read_bytes().count(b"\n") for p in files),
        "ks": [line["payload"]["k"] for line in read_recording(directory)],
    }


def disk_full(directory: Path, messages: list[str]) -> dict[str, Any]:
    filler = directory / "filler.bin"
    filler.write_bytes(b"\0" * FILLER_BYTES)
    recorder = Recorder(directory, max_bytes=1_000_000, max_files=10, retry_s=0.0).start()
    for k in range(400):  # about 70 KiB: more than the disk has left
        recorder.record("ips/v1/test", _payload(k), False)
    recorder.flush()
    full = {"written": recorder.lines_written, "dropped": recorder.lines_dropped, "paused": recorder.paused}
    filler.unlink()  # space comes back
    for k in range(400, 450):
        recorder.record("ips/v1/test", _payload(k), False)
    recorder.flush()
    after = {"written": recorder.lines_written, "dropped": recorder.lines_dropped, "paused": recorder.paused}
    recorder.close()
    return {"full": full, "after": after, **_files(directory), "log": messages}


def file_size_limit(directory: Path, messages: list[str]) -> dict[str, Any]:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write beyond the limit fails with EFBIG instead of killing
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_BYTES, FSIZE_BYTES))
    recorder = Recorder(directory, max_bytes=1_000_000, max_files=50).start()
    for k in range(300):
        recorder.record("ips/v1/test", _payload(k), False)
    recorder.close()
    counts = {"written": recorder.lines_written, "dropped": recorder.lines_dropped, "paused": recorder.paused}
    return {"after": counts, **_files(directory), "log": messages}


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(f"{record.levelname} {record.getMessage()}")


def main() -> None:
    scenario, directory = sys.argv[1], Path(sys.argv[2])
    collect = _Collect()
    logging.getLogger("edge.recording").addHandler(collect)
    logging.getLogger("edge.recording").setLevel(logging.INFO)
    run = {"disk-full": disk_full, "fsize": file_size_limit}[scenario]
    print(json.dumps(run(directory, collect.messages)))


if __name__ == "__main__":
    main()
