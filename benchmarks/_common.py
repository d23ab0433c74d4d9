"""What the benchmark and documentation scripts share: Debian's headless Chromium, a private Mosquitto, and
waiting for a process's readiness line.

Scripts import this module (``sys.path`` holds the repository's root), never the test suite; the tests take their
Chromium flags and the readiness wait from here too, so a page is measured and tested in the same browser and a
broker is started the same way.
"""

from __future__ import annotations

import os
import socket
import subprocess
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
MOSQUITTO = "/usr/sbin/mosquitto"
# What `edge-ips broker-config` writes, minus users and ACLs.
MOSQUITTO_BENCH = "allow_anonymous true\nset_tcp_nodelay true\npersistence false"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Broker:
    host: str
    port: int

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"


class ReadyLine:
    """A process's output copied line by line into ``log``, and an event for the line that says it is ready.

    :meth:`wait` returns True once ``is_ready(line)`` held for a line, False when the output ended first (the
    process exited) or ``timeout_s`` passed: the timeout is only a guard against a process that never says it.
    """

    def __init__(self, stream: IO[bytes], log: Path, is_ready: Callable[[bytes], bool]) -> None:
        self.ready = threading.Event()
        self._said = threading.Event()  # ready, or the output ended
        self._copied = threading.Condition()  # notified after each line reaches the log, and at the end
        self._ended = False
        self._thread = threading.Thread(target=self._copy, args=(stream, log, is_ready), daemon=True)
        self._thread.start()

    def _copy(self, stream: IO[bytes], log: Path, is_ready: Callable[[bytes], bool]) -> None:
        with stream, log.open("ab") as out:
            for line in stream:
                out.write(line)
                out.flush()
                with self._copied:
                    self._copied.notify_all()
                if not self.ready.is_set() and is_ready(line):
                    self.ready.set()
                    self._said.set()
        self._said.set()
        with self._copied:
            self._ended = True
            self._copied.notify_all()

    def wait(self, timeout_s: float) -> bool:
        self._said.wait(timeout_s)
        return self.ready.is_set()

    def wait_copied(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until ``done()`` holds, checked after each line is copied into the log (a line the process wrote
        is in the log only once this thread copied it); False when the output ended first or ``timeout_s``, a
        guard, passed."""
        with self._copied:
            return self._copied.wait_for(lambda: done() or self._ended, timeout_s) and done()


def mosquitto_running(line: bytes) -> bool:
    """Mosquitto's readiness line, logged once its listeners are open: ``mosquitto version 2.0.x running``."""
    return b"mosquitto version" in line and line.rstrip().endswith(b" running")


def start_mosquitto(
    conf: Path, log: Path, timeout_s: float = 10.0, open_files: int | None = None
) -> subprocess.Popen[bytes]:
    """``mosquitto -c conf`` (its config logging to stderr), its log appended to ``log``; returns once it says it
    is running. :class:`RuntimeError` with the log when it does not (a taken port, a bad line in ``conf``).
    ``open_files``: its file descriptor limit (systemd gives a service 1024)."""

    def limit_files() -> None:
        if open_files is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_NOFILE, (open_files, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    proc = subprocess.Popen(
        [MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=limit_files
    )
    assert proc.stderr is not None
    if not ReadyLine(proc.stderr, log, mosquitto_running).wait(timeout_s):
        stop_process(proc)
        raise RuntimeError(f"mosquitto did not start: {log.read_text()}")
    return proc


def stop_process(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL after 5 s."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@contextmanager
def private_mosquitto(
    workdir: Path, settings: str, timeout_s: float = 10.0, port: int | None = None
) -> Iterator[Broker]:
    """Debian's Mosquitto on a free loopback port (or ``port``) with ``settings`` (lines of mosquitto.conf, no
    listener), for as long as the ``with`` lasts."""
    workdir.mkdir(parents=True, exist_ok=True)
    broker = Broker("127.0.0.1", port or free_port())
    conf = workdir / "mosquitto.conf"
    # As root, Mosquitto would drop to its own user, which cannot read a private temporary directory.
    user = "user root\n" if os.geteuid() == 0 else ""
    conf.write_text(f"listener {broker.port} {broker.host}\nlog_dest stderr\n{user}{settings}\n")
    proc = start_mosquitto(conf, workdir / "mosquitto.log", timeout_s)
    try:
        yield broker
    finally:
        stop_process(proc)
