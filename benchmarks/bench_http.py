#!/usr/bin/env python3
"""HTTP server under abuse: does ``/healthz`` keep answering, and do threads stay bounded, while the port is held
by idle, half-open and slowloris connections?

    .venv/bin/python benchmarks/bench_http.py                 # ~1 min
    .venv/bin/python benchmarks/bench_http.py --requests 500 --trickle-s 30

What runs: ``edge-ips start --source sim`` as a real process (embedded broker on a free port, the HTTP server at
its defaults: 64 connections, 10 s request timeout). Phases, each timing ``--requests`` ``GET /healthz`` on a new
connection one after another:

* ``quiet``: nothing else connected (also ``/metrics`` scrapes: prometheus_client's exposition);
* ``flood``: 300 idle connections and 50 half-open requests (a request line and one header, never finished) opened
  just before; also the process's threads before and after, and how long until the server had closed every
  half-open one (evicted by the connection cap or timed out);
* ``slowloris``: 50 connections trickling one byte of header per second, held for ``--trickle-s`` seconds.

Counts (threads, connections closed) hold on any machine; the response times are to re-run on a quiet machine.
"""

from __future__ import annotations

import argparse
import contextlib
import http.client
import os
import platform
import re
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
PARTIAL_HEAD = b"GET /healthz HTTP/1.1\r\nHost: localhost\r\nX-Slow: "


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def healthz(port: int, path: str = "/healthz") -> tuple[int, float]:
    t0 = time.perf_counter()
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        conn.request("GET", path)
        resp = conn.getresponse()
        resp.read()
        return resp.status, time.perf_counter() - t0
    finally:
        conn.close()


def timed(port: int, n: int, path: str = "/healthz") -> dict[str, float]:
    results = [healthz(port, path) for _ in range(n)]
    ms = np.array([t for _, t in results]) * 1e3
    ok = sum(1 for status, _ in results if status in (200, 503))  # 503: degraded, still an answer
    return {
        "answered": ok,
        "n": n,
        "p50": round(float(np.percentile(ms, 50)), 2),
        "p99": round(float(np.percentile(ms, 99)), 2),
        "max": round(float(ms.max()), 2),
    }


def threads_of(pid: int) -> int:
    return int(Path(f"/proc/{pid}/status").read_text().split("Threads:")[1].split()[0])


def metric(port: int, name: str) -> float:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    conn.request("GET", "/metrics")
    text = conn.getresponse().read().decode()
    conn.close()
    match = re.search(rf"^{name} (\S+)$", text, re.M)
    return float(match.group(1)) if match else float("nan")


def wait_closed(socks: list[socket.socket], guard_s: float, since: float) -> float:
    """Seconds from ``since`` (monotonic) until the server has closed every socket (waiting at most ``guard_s``)."""
    t0 = time.monotonic()
    sel = selectors.DefaultSelector()
    for s in socks:
        sel.register(s, selectors.EVENT_READ)
    open_ = set(socks)
    while open_ and time.monotonic() - t0 < guard_s:
        for key, _ in sel.select(timeout=0.5):
            sock = key.fileobj
            try:
                data = sock.recv(4096)  # type: ignore[union-attr]
            except OSError:
                data = b""
            if not data:
                sel.unregister(sock)
                open_.discard(sock)  # type: ignore[arg-type]
    return time.monotonic() - since


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=200, help="GET /healthz timed per phase")
    parser.add_argument("--trickle-s", type=float, default=15.0, help="how long the slowloris phase lasts")
    args = parser.parse_args()

    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    env.update(PYTHONPATH=str(REPO), EDGE_IPS_BROKER__EMBEDDED_PORT="0", EDGE_IPS_BROKER__EMBEDDED_HOST="127.0.0.1")
    with tempfile.TemporaryDirectory(prefix="bench-http-") as tmp:
        log_path = Path(tmp) / "edge.log"
        with log_path.open("w") as log:
            edge = subprocess.Popen(
                [sys.executable, "-m", "edge.cli", "start", "--source", "sim", "--http-port", str(port)],
                cwd=tmp,
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        try:
            deadline = time.monotonic() + 120
            while True:
                try:
                    if healthz(port)[0] == 200:
                        break
                except OSError:
                    pass
                if edge.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"edge-ips start did not come online:\n{log_path.read_text()}")
                time.sleep(0.2)
            metric(port, "edge_ips_fps")  # the worker threads exist before the first thread count
            rows = {"quiet": timed(port, args.requests)}
            scrape = timed(port, args.requests // 4, "/metrics")  # prometheus_client's exposition, on a worker thread

            before = threads_of(edge.pid)
            idle = [socket.create_connection(("127.0.0.1", port)) for _ in range(300)]
            half_open = [socket.create_connection(("127.0.0.1", port)) for _ in range(50)]
            for s in half_open:
                s.sendall(PARTIAL_HEAD)
            opened = time.monotonic()
            rows["flood"] = timed(port, args.requests)
            during = threads_of(edge.pid)
            open_during = metric(port, "edge_ips_http_connections_open")
            closed_s = wait_closed(half_open, 60.0, opened)
            evicted = metric(port, "edge_ips_http_connections_evicted_total")
            timeouts = metric(port, "edge_ips_http_request_timeouts_total")
            for s in idle + half_open:
                s.close()

            trickling = [socket.create_connection(("127.0.0.1", port)) for _ in range(50)]
            for s in trickling:
                s.sendall(PARTIAL_HEAD)
            stop = threading.Event()

            def trickle() -> None:
                while not stop.wait(1.0):
                    for s in trickling:
                        with contextlib.suppress(OSError):  # closed by the server: what should happen
                            s.sendall(b"x")

            feeder = threading.Thread(target=trickle, daemon=True)
            feeder.start()
            t0 = time.monotonic()
            slow_rows = []
            while time.monotonic() - t0 < args.trickle_s:
                slow_rows.append(timed(port, max(1, args.requests // 10)))
            slow_closed_s = wait_closed(trickling, 60.0, time.monotonic())
            stop.set()
            feeder.join()
            for s in trickling:
                s.close()
            answered = sum(r["answered"] for r in slow_rows)
            total = sum(r["n"] for r in slow_rows)
            rows["slowloris"] = {
                "answered": answered,
                "n": total,
                "p50": round(float(np.median([r["p50"] for r in slow_rows])), 2),
                "p99": round(float(max(r["p99"] for r in slow_rows)), 2),
                "max": round(float(max(r["max"] for r in slow_rows)), 2),
            }
            after = threads_of(edge.pid)
        finally:
            edge.send_signal(signal.SIGTERM)
            try:
                edge.wait(30)
            except subprocess.TimeoutExpired:
                edge.kill()
            noisy = [ln for ln in log_path.read_text().splitlines() if " ERROR " in ln or "Traceback" in ln]

    load = os.getloadavg()
    print(
        f"machine: {platform.node()} ({os.cpu_count()} cores {platform.machine()}), Python "
        f"{platform.python_version()}, {time.strftime('%Y-%m-%d')}, load average at the end "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
    )
    print()
    print("| phase | /healthz answered | p50 / p99 / max (ms) |")
    print("| --- | --- | --- |")
    for name, r in rows.items():
        print(f"| {name} | {r['answered']} / {r['n']} | {r['p50']} / {r['p99']} / {r['max']} |")
    print()
    print(
        f"GET /metrics (quiet, {scrape['n']} scrapes, prometheus_client): p50 / p99 / max "
        f"{scrape['p50']} / {scrape['p99']} / {scrape['max']} ms"
    )
    print(f"threads: {before} before the flood, {during} during it, {after} after the slowloris phase")
    print(f"connections open during the flood (of 351 made): {open_during:g}")
    print(
        f"half-open requests all closed by the server {closed_s:.1f} s after they were opened "
        f"({evicted:g} connections evicted, {timeouts:g} timed out)"
    )
    print(f"slowloris connections all closed by the server {slow_closed_s:.1f} s after the phase")
    print(f"error lines in the edge's log: {len(noisy)}" + "".join(f"\n    {ln}" for ln in noisy[:5]))


if __name__ == "__main__":
    main()
