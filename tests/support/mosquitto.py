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


def free_port(taken: set[int] | None = None) -> int:
    """A port free now on loopback, none of ``taken`` (the system may hand a port just given out, and closed, again:
    two listeners of one broker were once given the same port, and it did not start)."""
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
