"""What the benchmark and documentation scripts share: Debian's headless Chromium and a private Mosquitto.

Scripts import this module (``sys.path`` holds the repository's root), never the test suite; the tests take their
Chromium flags from here too, so a page is measured and tested in the same browser.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

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


@contextmanager
def private_mosquitto(workdir: Path, settings: str, timeout_s: float = 10.0) -> Iterator[Broker]:
    """Debian's Mosquitto on a free loopback port with ``settings`` (lines of mosquitto.conf, no listener), for
    as long as the ``with`` lasts."""
    workdir.mkdir(parents=True, exist_ok=True)
    broker = Broker("127.0.0.1", free_port())
    conf = workdir / "mosquitto.conf"
    # As root, Mosquitto would drop to its own user, which cannot read a private temporary directory.
    user = "user root\n" if os.geteuid() == 0 else ""
    conf.write_text(f"listener {broker.port} {broker.host}\nlog_dest stderr\n{user}{settings}\n")
    log = workdir / "mosquitto.log"
    with log.open("ab") as err:
        proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=err)
    try:
        deadline = time.monotonic() + timeout_s
        while True:  # a process we do not control: its port is the only sign that it is ready
            try:
                socket.create_connection((broker.host, broker.port), timeout=0.2).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"mosquitto did not start: {log.read_text()}") from None
                time.sleep(0.05)
        yield broker
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
