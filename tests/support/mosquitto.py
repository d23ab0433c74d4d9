"""A private Mosquitto broker per test: own port, own config, own users and ACLs. Never a shared broker."""

from __future__ import annotations

import os
import socket
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks._common import start_mosquitto, stop_process
from edge.broker import write_password_file


def _listener_ports() -> range:
    """This process's share of the ports below the system's ephemeral range. A port from ``bind(0)`` is itself
    ephemeral: any outgoing connection (another test's client, a worker beside this one) may take it as its local
    port before the listener it was chosen for binds, and the listener then fails with "already in use". Ports below
    the range are never handed out that way; each pytest-xdist worker gets its own slice of them. Empty where the
    range starts too low to leave room."""
    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        low = 32768
    start = 10000 if low > 12000 else 1024
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    slices = max(int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")), 1)
    size = max(low - start, 0) // slices
    if size < 100:
        return range(0)
    first = start + (int(worker) if worker.isdigit() else 0) % slices * size
    return range(first, first + size)


_PORTS = _listener_ports()
_next = [int.from_bytes(os.urandom(2), "big")]  # a run starts anywhere in the slice


def free_port(taken: set[int] | None = None) -> int:
    """A port free now on loopback, none of ``taken``: the next of this process's listener ports
    (:func:`_listener_ports`) that binds; no port is given out twice in the slice's round (the system would hand a
    port just closed again: two listeners of one broker were once given the same port, and it did not start).
    Without such ports, one from the system (``bind(0)``)."""
    for _ in range(len(_PORTS)):
        port = _PORTS[_next[0] % len(_PORTS)]
        _next[0] += 1
        if port in (taken or set()):
            continue
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port not in (taken or set()):
            return port


def _user_line() -> str:
    # Run as root, mosquitto drops to the `mosquitto` user, which cannot read files under pytest's private tmp.
    return "user root\n" if os.geteuid() == 0 else ""


@dataclass
class Mosquitto:
    """A Mosquitto process with its own config in ``workdir``.

    ``users``: name -> password (anonymous access is then off unless ``allow_anonymous``); ``acl``: the text of
    an ACL file. ``conf_path`` may point at a complete config (e.g. one written by ``edge-ips broker-config``):
    then each listener moves to a free port on ``host`` (:attr:`ports`; the first one is :attr:`port`).
    """

    workdir: Path
    port: int = field(default_factory=free_port)
    users: Mapping[str, str] | None = None
    acl: str | None = None
    allow_anonymous: bool = True
    conf_path: Path | None = None
    host: str = "127.0.0.1"
    proc: subprocess.Popen[bytes] | None = None
    ports: dict[int, int] = field(default_factory=dict)  # a conf_path's listener port -> this instance's
    open_files: int | None = None  # the process's file descriptor limit (None: this process's)

    def _write_config(self) -> Path:
        self.workdir.mkdir(parents=True, exist_ok=True)
        if self.conf_path is not None:
            # Each listener of the file moves to a free port on this host (the first to self.port); the options
            # that follow a listener line stay with it.
            lines = [f"log_dest stderr\n{_user_line()}"]
            for line in self.conf_path.read_text().splitlines():
                if line.strip().startswith(("port ", "log_dest", "pid_file")):
                    continue
                if line.strip().startswith("listener"):
                    original = int(line.split()[1])
                    if original not in self.ports:
                        taken = {self.port, *self.ports.values()}
                        self.ports[original] = self.port if not self.ports else free_port(taken)
                    port = self.ports[original]
                    line = f"listener {port} {self.host}"
                lines.append(line)
            if not self.ports:  # a file without listeners: its options are for this instance's one listener
                lines.insert(1, f"listener {self.port} {self.host}")
            conf = self.workdir / "mosquitto-test.conf"
            conf.write_text("\n".join(lines) + "\n")
            return conf
        lines = [
            f"listener {self.port} {self.host}",
            "persistence false",
            "log_dest stderr",
            _user_line(),
            f"allow_anonymous {'true' if self.allow_anonymous and not self.users else 'false'}",
        ]
        if self.users:
            pw = write_password_file(self.workdir / "passwd", self.users)  # never a password on a command line
            lines.append(f"password_file {pw}")
        if self.acl is not None:
            acl = self.workdir / "acl"
            acl.write_text(self.acl)
            acl.chmod(0o600)
            lines.append(f"acl_file {acl}")
        conf = self.workdir / "mosquitto.conf"
        conf.write_text("\n".join(lines) + "\n")
        return conf

    def start(self, timeout_s: float = 10.0) -> Mosquitto:
        """Start the process and wait for its readiness line (logged once its listeners are open); ``timeout_s``
        only guards against a broker that never says it."""
        self.proc = start_mosquitto(self._write_config(), self.workdir / "mosquitto.log", timeout_s, self.open_files)
        return self

    def stop(self) -> None:
        if self.proc is not None:
            stop_process(self.proc)
        self.proc = None

    def restart(self) -> None:
        self.stop()
        self.start()

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    def __enter__(self) -> Mosquitto:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
