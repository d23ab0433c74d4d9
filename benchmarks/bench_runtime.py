#!/usr/bin/env python3
"""Runtime benchmark: end-to-end latency, CPU and memory of ``edge-ips start``.

    .venv/bin/python benchmarks/bench_runtime.py                       # 10 min with Mosquitto, 10 min embedded
    .venv/bin/python benchmarks/bench_runtime.py --duration 60 --brokers mosquitto

What runs, as on the camera board: a pre-rendered 1280x720 clip (3 rovers, MJPG, looped at 30 fps: rendering is
not counted as the edge's work, decoding is, as for a real MJPG webcam) -> ``edge-ips start`` in its own process
-> a broker (a private Mosquitto that this script starts, or the edge's embedded amqtt) -> a separate subscriber
process on ``ips/v1/rovers/+/pose``.

* End-to-end latency = the subscriber's receive time minus the pose's ``t`` (the wall-clock time taken when the
  frame was grabbed, before decoding). Same machine, same clock; ``t`` has 1 ms resolution on the wire, so each
  sample carries a uniform +-0.5 ms rounding (the median is unbiased). Reported overall and per minute.
* CPU: the edge process (all its threads, the embedded broker included when used), sampled every second with
  psutil; 100 % = one core. Memory: resident set size, first and last minute.

The clip is the simulator's ``lab`` scenario (seed 0), calibrated with the simulated camera's exact calibration;
the edge runs its real tracking pipeline (``[tracker]`` defaults).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


# -- subscriber mode (a separate process) --------------------------------------------------------------------------
def subscriber(host: str, port: int, out: Path) -> None:
    """Record (t_recv - t, t, id) for every pose until SIGTERM, then write them as JSON."""
    import paho.mqtt.client as mqtt

    samples: list[tuple[float, float, str]] = []
    stop = threading.Event()

    def on_connect(c: Any, u: Any, flags: Any, rc: Any, props: Any) -> None:
        c.subscribe("ips/v1/rovers/+/pose", qos=0)

    def on_message(c: Any, u: Any, msg: Any) -> None:
        t_recv = time.time()
        pose = json.loads(msg.payload)
        samples.append((t_recv - pose["t"], pose["t"], pose["id"]))

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-subscriber")
    client.on_connect, client.on_message = on_connect, on_message
    client.reconnect_delay_set(1, 2)
    client.connect_async(host, port, keepalive=10)
    client.loop_start()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    print("subscribed", flush=True)
    stop.wait()
    client.loop_stop()
    out.write_text(json.dumps(samples))


# -- the clip ------------------------------------------------------------------------------------------------------
def render_clip(directory: Path, width: int, height: int, fps: float, seconds: float) -> tuple[Path, Path, str]:
    """An MJPG clip of the simulator's 3 moving rovers and its exact calibration file."""
    import cv2

    clip = directory / "clip.avi"
    frames = int(seconds * fps)
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter.fourcc(*"MJPG"), fps, (width, height))
    from edge.calibration import save_calibration
    from edge.calibration.exact import exact_calibration
    from edge.sim.source import SimSource

    sim = SimSource("lab", seed=0, realtime=False, frames=frames)
    info = sim.open()
    if (info.width_px, info.height_px) != (width, height):
        raise SystemExit(f"the simulator renders {info.width_px}x{info.height_px}, not {width}x{height}")
    while (frame := sim.read()) is not None:
        writer.write(frame.image)
    calibration = directory / "calibration.json"
    save_calibration(exact_calibration(sim.setup.camera), calibration)
    what = "simulator scenario 'lab', seed 0, with its exact calibration"
    sim.close()
    writer.release()
    return clip, calibration, what


# -- one run -------------------------------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class RunResult:
    broker: str
    tracker: str
    duration_s: float
    poses_received: int
    poses_per_s: float
    e2e_p50_ms: float
    e2e_p90_ms: float
    e2e_p99_ms: float
    e2e_max_ms: float
    per_minute_p50_ms: list[float]
    per_minute_p99_ms: list[float]
    cpu_mean_pct: float
    cpu_p95_pct: float
    rss_first_min_mb: float
    rss_last_min_mb: float
    rss_max_mb: float
    per_minute_rss_mb: list[float]
    fps: float
    frames_dropped: int
    processing_p50_ms: float
    processing_p99_ms: float
    grab_to_publish_p50_ms: float
    grab_to_publish_p99_ms: float


def _metric(text: str, name: str) -> float:
    for line in text.splitlines():
        if line.startswith(f"edge_ips_{name} "):
            return float(line.split()[-1])
    return float("nan")


def _wait_http(url: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=2):
                return
        except urllib.error.HTTPError:
            return  # 503 while degraded: it is up
        except OSError:
            time.sleep(0.2)
    raise RuntimeError(f"the edge did not come up at {url}")


def run_once(
    broker_kind: str, clip: Path, calibration: Path, duration_s: float, warmup_s: float, workdir: Path
) -> RunResult:
    import psutil
    from _common import MOSQUITTO_BENCH, private_mosquitto

    from edge.config_text import to_toml

    http_port = free_port()
    settings: dict[str, dict[str, Any]] = {
        "edge": {"id": "bench", "status_interval_s": 2.0},
        "camera": {"source": str(clip), "loop": True, "realtime": True},
        "http": {"enabled": True, "host": "127.0.0.1", "port": http_port},
        "broker": {"reconnect_max_s": 2.0},
    }
    settings["calibration"] = {"path": str(calibration)}
    brokers = contextlib.ExitStack()
    if broker_kind == "mosquitto":
        mosquitto = brokers.enter_context(private_mosquitto(workdir / "mosquitto", MOSQUITTO_BENCH))
        settings["broker"]["url"] = mosquitto.url
        broker_port = mosquitto.port
    else:
        broker_port = free_port()
        settings["broker"].update(url="embedded", embedded_host="127.0.0.1", embedded_port=broker_port)

    config = workdir / f"{broker_kind}.toml"
    config.write_text(to_toml(settings))
    cmd = [sys.executable, "-m", "edge.cli", "start", "--config", str(config)]  # = edge-ips start, this checkout
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    edge_log = open(workdir / f"edge-{broker_kind}.log", "wb")  # noqa: SIM115 - closed below
    edge = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=edge_log, stderr=subprocess.STDOUT)
    samples_path = workdir / f"samples-{broker_kind}.json"
    sub = None
    try:
        _wait_http(f"http://127.0.0.1:{http_port}/healthz", 60)
        sub = subprocess.Popen(
            [sys.executable, __file__, "--subscriber", "127.0.0.1", str(broker_port), str(samples_path)],
            cwd=REPO,
            stdout=subprocess.PIPE,
        )
        assert sub.stdout is not None
        sub.stdout.readline()
        proc = psutil.Process(edge.pid)
        time.sleep(warmup_s)
        proc.cpu_percent(None)
        t_start = time.time()
        cpu, rss, rss_t = [], [], []
        while time.time() - t_start < duration_s:
            time.sleep(1.0)
            cpu.append(proc.cpu_percent(None))
            rss.append(proc.memory_info().rss / 2**20)
            rss_t.append(time.time() - t_start)
        t_end = time.time()
        with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/metrics", timeout=5) as resp:
            metrics = resp.read().decode()
    finally:
        if sub is not None:
            sub.send_signal(signal.SIGTERM)
            sub.wait(30)
        edge.send_signal(signal.SIGTERM)
        try:
            edge.wait(30)
        except subprocess.TimeoutExpired:
            edge.kill()
        edge_log.close()
        brokers.close()

    raw = json.loads(samples_path.read_text())
    data = np.array([(lat, t) for lat, t, _ in raw if t_start <= t <= t_end], dtype=np.float64).reshape(-1, 2)
    lat_ms = data[:, 0] * 1e3
    minutes = max(1, round(duration_s / 60))
    edges = np.linspace(t_start, t_end, minutes + 1)
    per_p50, per_p99 = [], []
    for a, b in itertools.pairwise(edges):
        chunk = lat_ms[(data[:, 1] >= a) & (data[:, 1] < b)]
        per_p50.append(round(float(np.percentile(chunk, 50)), 2) if chunk.size else float("nan"))
        per_p99.append(round(float(np.percentile(chunk, 99)), 2) if chunk.size else float("nan"))
    rss_a = np.array(rss)
    rss_t_a = np.array(rss_t)
    first = rss_a[rss_t_a <= 60] if (rss_t_a <= 60).any() else rss_a[:1]
    last = rss_a[rss_t_a >= rss_t_a[-1] - 60]
    return RunResult(
        broker=broker_kind,
        tracker="pipeline (particles)",
        duration_s=round(t_end - t_start, 1),
        poses_received=int(lat_ms.size),
        poses_per_s=round(lat_ms.size / (t_end - t_start), 1),
        e2e_p50_ms=round(float(np.percentile(lat_ms, 50)), 2),
        e2e_p90_ms=round(float(np.percentile(lat_ms, 90)), 2),
        e2e_p99_ms=round(float(np.percentile(lat_ms, 99)), 2),
        e2e_max_ms=round(float(lat_ms.max()), 2),
        per_minute_p50_ms=per_p50,
        per_minute_p99_ms=per_p99,
        cpu_mean_pct=round(float(np.mean(cpu)), 1),
        cpu_p95_pct=round(float(np.percentile(cpu, 95)), 1),
        rss_first_min_mb=round(float(first.mean()), 1),
        rss_last_min_mb=round(float(last.mean()), 1),
        rss_max_mb=round(float(rss_a.max()), 1),
        per_minute_rss_mb=[
            round(float(rss_a[(rss_t_a > 60 * k) & (rss_t_a <= 60 * (k + 1))].mean()), 1) for k in range(minutes)
        ],
        fps=round(_metric(metrics, "fps"), 1),
        frames_dropped=int(_metric(metrics, "frames_dropped_total")),
        processing_p50_ms=round(_metric(metrics, 'processing_seconds{quantile="0.5"}') * 1e3, 2),
        processing_p99_ms=round(_metric(metrics, 'processing_seconds{quantile="0.99"}') * 1e3, 2),
        grab_to_publish_p50_ms=round(_metric(metrics, 'end_to_end_seconds{quantile="0.5"}') * 1e3, 2),
        grab_to_publish_p99_ms=round(_metric(metrics, 'end_to_end_seconds{quantile="0.99"}') * 1e3, 2),
    )


def table(results: list[RunResult]) -> str:
    rows = [
        ("tracker", lambda r: r.tracker),
        ("measured for", lambda r: f"{r.duration_s:.0f} s"),
        ("poses received / s", lambda r: f"{r.poses_per_s:g}"),
        ("edge fps", lambda r: f"{r.fps:g}"),
        ("end-to-end p50 / p90 / p99 (ms)", lambda r: f"{r.e2e_p50_ms} / {r.e2e_p90_ms} / {r.e2e_p99_ms}"),
        ("end-to-end max (ms)", lambda r: f"{r.e2e_max_ms}"),
        ("p50 per minute (ms)", lambda r: ", ".join(f"{v:g}" for v in r.per_minute_p50_ms)),
        ("p99 per minute (ms)", lambda r: ", ".join(f"{v:g}" for v in r.per_minute_p99_ms)),
        ("tracker processing p50 / p99 (ms)", lambda r: f"{r.processing_p50_ms} / {r.processing_p99_ms}"),
        ("grab to publish p50 / p99 (ms)", lambda r: f"{r.grab_to_publish_p50_ms} / {r.grab_to_publish_p99_ms}"),
        ("CPU mean / p95 (% of one core)", lambda r: f"{r.cpu_mean_pct} / {r.cpu_p95_pct}"),
        (
            "RSS first min / last min / max (MiB)",
            lambda r: f"{r.rss_first_min_mb} / {r.rss_last_min_mb} / {r.rss_max_mb}",
        ),
        ("RSS per minute (MiB)", lambda r: ", ".join(f"{v:g}" for v in r.per_minute_rss_mb)),
        ("frames dropped (overwritten)", lambda r: f"{r.frames_dropped}"),
    ]
    head = "| | " + " | ".join(f"{r.broker}" for r in results) + " |"
    sep = "| --- |" + " --- |" * len(results)
    body = [f"| {name} | " + " | ".join(str(fn(r)) for r in results) + " |" for name, fn in rows]
    return "\n".join([head, sep, *body])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=600.0, help="seconds measured per broker (default 600)")
    parser.add_argument("--warmup", type=float, default=5.0, help="seconds before measuring")
    parser.add_argument("--brokers", default="mosquitto,embedded", help="mosquitto, embedded or both")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument("--subscriber", nargs=3, metavar=("HOST", "PORT", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        subscriber(args.subscriber[0], int(args.subscriber[1]), Path(args.subscriber[2]))
        return
    width, height = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as tmp:
        workdir = Path(tmp)
        clip, calibration, what = render_clip(workdir, width, height, args.fps, seconds=10.0)
        print(f"clip: {width}x{height} @ {args.fps:g} fps, 3 rovers, {what}; looped", flush=True)
        results = []
        for kind in [b.strip() for b in args.brokers.split(",") if b.strip()]:
            print(f"running {kind} for {args.duration:g} s ...", flush=True)
            results.append(run_once(kind, clip, calibration, args.duration, args.warmup, workdir))
    cpu = f"{os.cpu_count()} cores {platform.machine()}"
    print(f"\nmachine: {platform.node()} ({cpu}), Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}")
    print(table(results))
    if args.json is not None:
        args.json.write_text(json.dumps([asdict(r) for r in results], indent=2))


if __name__ == "__main__":
    main()
