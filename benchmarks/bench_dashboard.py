#!/usr/bin/env python3
"""Dashboard benchmark: does watching the page slow the tracker? Tracker processing p99 with and without
viewers connected (bar: no more than 10 % worse), and what the viewers get.

    .venv/bin/python benchmarks/bench_dashboard.py                     # 3 rounds x 4 conditions x 40 s, ~9 min
    .venv/bin/python benchmarks/bench_dashboard.py --rounds 1 --phase 20 --viewers none,client

What runs, as on the camera board: the simulator's ``lab`` scenario (3 rovers, seed 0) pre-rendered to a 1280x720
MJPG clip, looped and paced at 30 fps (as ``bench_runtime.py``: rendering is not the edge's work, decoding is),
through the appliance exactly as ``edge-ips start`` assembles it (:func:`edge.appliance.prepare_appliance`: real
tracking pipeline with ``[tracker]`` defaults, the clip's exact calibration, a private Mosquitto, the HTTP server
with the dashboard at its defaults: 10 fps JPEG at 960 px, quality 70, 15 Hz poses). The appliance runs in this
process; the benchmark's own thread only sleeps. The tracker's time per frame is taken around
``Tracker.process`` (what the runtime reports as processing time) and attributed to the condition running then.

Conditions, alternated round after round so slow drifts of the shared machine hit all of them alike:

* ``none``: nobody watching (the encoder and event threads asleep);
* ``client``: one viewer in its own process doing what the page does: one event stream, camera frames fetched
  back to back (the next request as soon as one arrives);
* ``clients3``: three such viewers (frames are still encoded once);
* ``chromium``: the real page in Debian's headless chromium, on the same 2 cores as the edge (a harsher case
  than a laptop across the network).

The viewers run at nice 19: they stand in for a laptop elsewhere, so they should take as little of the edge's two
cores as they can (they still take some: "viewer CPU" in the table, per viewer).

The first ``--settle`` seconds of every phase (viewers connecting, threads waking) are not counted.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from _common import CHROMIUM, CHROMIUM_ARGS, MOSQUITTO_BENCH, private_mosquitto  # noqa: E402  (after sys.path)


# -- viewer processes ----------------------------------------------------------------------------------------------
def viewer_client(port: int, out: Path) -> None:
    """Until SIGTERM: read /api/events and fetch /api/frame.jpg back to back; write what arrived as JSON."""
    stop = threading.Event()
    counts = {"pose": 0, "status": 0, "frames": 0, "jpeg_bytes": 0}

    def events() -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        conn.request("GET", "/api/events")
        resp = conn.getresponse()
        while not stop.is_set():
            line = resp.fp.readline()
            if not line:
                break
            if line.startswith(b"event: "):
                name = line[7:].strip().decode()
                counts[name] = counts.get(name, 0) + 1

    def frames() -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        conn.request("GET", "/api/state")
        conn.getresponse().read()
        while not stop.is_set():
            conn.request("GET", "/api/frame.jpg")
            body = conn.getresponse().read()
            counts["frames"] += 1
            counts["jpeg_bytes"] += len(body)

    for target in (events, frames):
        threading.Thread(target=target, daemon=True).start()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    t0, cpu0 = time.monotonic(), time.process_time()
    print("watching", flush=True)
    stop.wait()
    seconds = time.monotonic() - t0
    cpu_pct = 100.0 * (time.process_time() - cpu0) / seconds
    out.write_text(json.dumps({**counts, "seconds": seconds, "cpu_pct": cpu_pct}))


def viewer_chromium(port: int, out: Path) -> None:
    """Until SIGTERM: the real page in headless chromium; counts the camera frames it loaded."""
    import psutil
    from playwright.sync_api import sync_playwright

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_function("() => state.rovers.size > 0", timeout=60_000)
        t0 = time.monotonic()
        cpu0 = sum(sum(c.cpu_times()[:2]) for c in psutil.Process().children(recursive=True))
        print("watching", flush=True)
        while not stop.is_set():
            page.wait_for_timeout(200)
        frames = page.evaluate("() => frameCount")
        seconds = time.monotonic() - t0
        cpu_s = sum(sum(c.cpu_times()[:2]) for c in psutil.Process().children(recursive=True)) - cpu0
        out.write_text(json.dumps({"frames": frames, "seconds": seconds, "cpu_pct": 100.0 * cpu_s / seconds}))
        browser.close()


# -- the appliance -------------------------------------------------------------------------------------------------
class TimedTracker:
    """Wraps the real tracker: (end time, seconds) of every ``process`` call."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.samples: list[tuple[float, float]] = []

    def process(self, frame: Any) -> Any:
        t0 = time.perf_counter()
        result = self.inner.process(frame)
        t1 = time.perf_counter()
        self.samples.append((time.monotonic(), t1 - t0))
        return result

    def reset(self) -> None:
        self.inner.reset()

    def close(self) -> None:
        self.inner.close()


@dataclass
class Phase:
    condition: str
    t0: float
    t1: float
    viewers: list[dict[str, Any]] = field(default_factory=list)
    cpu_s: float = 0.0


def start_viewers(condition: str, port: int, workdir: Path, k: int) -> list[tuple[subprocess.Popen[bytes], Path]]:
    kind, n = {"none": ("", 0), "client": ("client", 1), "clients3": ("client", 3), "chromium": ("chromium", 1)}[
        condition
    ]
    procs = []
    for i in range(n):
        out = workdir / f"viewer-{condition}-{k}-{i}.json"
        proc = subprocess.Popen(
            [sys.executable, __file__, f"--viewer-{kind}", str(port), str(out)],
            cwd=REPO,
            stdout=subprocess.PIPE,
            preexec_fn=lambda: os.nice(19),  # a stand-in for a laptop elsewhere: it yields these cores to the edge
        )
        procs.append((proc, out))
    for proc, _ in procs:
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != b"watching":
            raise SystemExit(f"viewer {condition} did not start")
    return procs


def stop_viewers(procs: list[tuple[subprocess.Popen[bytes], Path]]) -> list[dict[str, Any]]:
    got = []
    for proc, out in procs:
        proc.send_signal(signal.SIGTERM)
        proc.wait(60)
        got.append(json.loads(out.read_text()))
    return got


def quantiles_ms(values: np.ndarray) -> dict[str, float]:
    ms = values * 1e3
    return {
        "n": int(ms.size),
        "p50": round(float(np.percentile(ms, 50)), 2),
        "p90": round(float(np.percentile(ms, 90)), 2),
        "p99": round(float(np.percentile(ms, 99)), 2),
        "max": round(float(ms.max()), 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--phase", type=float, default=40.0, help="seconds per condition per round")
    parser.add_argument("--settle", type=float, default=4.0, help="seconds not counted at the start of a phase")
    parser.add_argument("--viewers", default="none,client,clients3,chromium")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--viewer-client", nargs=2, metavar=("PORT", "OUT"), help=argparse.SUPPRESS)
    parser.add_argument("--viewer-chromium", nargs=2, metavar=("PORT", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.viewer_client:
        viewer_client(int(args.viewer_client[0]), Path(args.viewer_client[1]))
        return
    if args.viewer_chromium:
        viewer_chromium(int(args.viewer_chromium[0]), Path(args.viewer_chromium[1]))
        return

    import logging

    import psutil
    from bench_runtime import render_clip

    from edge.appliance import default_tracker_factory, prepare_appliance
    from edge.config import EdgeConfig
    from edge.config_load import with_overrides

    logging.basicConfig(level=logging.WARNING)
    conditions = [c.strip() for c in args.viewers.split(",") if c.strip()]
    with tempfile.TemporaryDirectory(prefix="bench-dashboard-") as tmp:
        workdir = Path(tmp)
        clip, calibration, what = render_clip(workdir, 1280, 720, 30.0, seconds=10.0)
        print(f"clip: 1280x720 @ 30 fps, 3 rovers, {what}; looped", flush=True)
        with private_mosquitto(workdir / "mosquitto", MOSQUITTO_BENCH) as mosquitto:
            config = with_overrides(
                EdgeConfig(),
                **{
                    "edge.id": "bench",
                    "camera.source": str(clip),
                    "camera.loop": True,
                    "camera.realtime": True,
                    "calibration.path": str(calibration),
                    "broker.url": mosquitto.url,
                    "http.host": "127.0.0.1",
                    "http.port": 0,
                },
            )
            timed: list[TimedTracker] = []

            def factory(inputs: Any) -> Any:
                timed.append(TimedTracker(default_tracker_factory(inputs)))
                return timed[-1]

            app = prepare_appliance(config, tracker_factory=factory)
            stop = threading.Event()
            runner = threading.Thread(target=app.run, args=(stop,), daemon=True)
            runner.start()
            port = app.http.port
            me = psutil.Process()
            phases: list[Phase] = []
            try:
                time.sleep(5.0)  # warm-up: filters converge, caches fill
                for k in range(args.rounds):
                    for condition in conditions:
                        procs = start_viewers(condition, port, workdir, k)
                        time.sleep(args.settle)
                        cpu0 = sum(me.cpu_times()[:2])
                        t0 = time.monotonic()
                        time.sleep(args.phase)
                        t1 = time.monotonic()
                        phase = Phase(condition, t0, t1, cpu_s=sum(me.cpu_times()[:2]) - cpu0)
                        phase.viewers = stop_viewers(procs)
                        phases.append(phase)
                        print(f"round {k + 1}: {condition} done", flush=True)
                encoder = app.dashboard.encoder
                encode_ms = [round(v * 1e3, 2) for v in encoder.encode_time.quantiles((0.5, 0.99))]
            finally:
                stop.set()
                runner.join(30)

    samples = np.array(timed[0].samples, dtype=np.float64)
    rows: dict[str, dict[str, Any]] = {}
    for condition in conditions:
        mine = [p for p in phases if p.condition == condition]
        mask = np.zeros(len(samples), dtype=bool)
        for p in mine:
            mask |= (samples[:, 0] >= p.t0) & (samples[:, 0] < p.t1)
        seconds = sum(p.t1 - p.t0 for p in mine)
        per_round = []
        for p in mine:
            sel = (samples[:, 0] >= p.t0) & (samples[:, 0] < p.t1)
            per_round.append(round(float(np.percentile(samples[sel, 1] * 1e3, 99)), 2))
        viewers = [v for p in mine for v in p.viewers]
        frames = sum(v.get("frames", 0) for v in viewers)
        viewer_s = sum(v["seconds"] for v in viewers)
        rows[condition] = {
            **quantiles_ms(samples[mask, 1]),
            "p99_per_round": per_round,
            "fps": round(float(mask.sum()) / seconds, 2),
            "cpu_pct": round(100.0 * sum(p.cpu_s for p in mine) / seconds, 1),
            "viewer_frames_per_s": round(frames / viewer_s, 2) if viewers else None,
            "viewer_pose_events_per_s": round(sum(v.get("pose", 0) for v in viewers) / viewer_s, 2)
            if viewers and "pose" in viewers[0]
            else None,
            "viewer_cpu_pct": round(float(np.mean([v["cpu_pct"] for v in viewers])), 1)
            if viewers and "cpu_pct" in viewers[0]
            else None,
            "jpeg_kb": round(sum(v.get("jpeg_bytes", 0) for v in viewers) / max(1, frames) / 1024, 1)
            if viewers and "jpeg_bytes" in viewers[0]
            else None,
        }
    base = rows.get("none")
    load = os.getloadavg()
    print(
        f"\nmachine: {platform.node()} ({os.cpu_count()} cores {platform.machine()}), Python "
        f"{platform.python_version()}, {time.strftime('%Y-%m-%d')}, load average at the end "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
    )
    print(f"{args.rounds} rounds x {args.phase:g} s per condition ({args.settle:g} s settling not counted)")
    print(f"JPEG encoding (1280x720 -> 960x540, quality 70) p50 / p99: {encode_ms[0]} / {encode_ms[1]} ms")
    print()
    print(
        "| condition | frames | tracker p50 / p90 / p99 / max (ms) | p99 per round (ms) | p99 vs none | fps "
        "| edge CPU (% of a core) | frames/s per viewer | pose events/s per viewer | JPEG KiB | viewer CPU |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for condition, r in rows.items():
        change = "" if base is None or condition == "none" else f"{100.0 * (r['p99'] / base['p99'] - 1.0):+.1f} %"
        print(
            f"| {condition} | {r['n']} | {r['p50']} / {r['p90']} / {r['p99']} / {r['max']} | "
            f"{', '.join(str(v) for v in r['p99_per_round'])} | {change} | {r['fps']} | {r['cpu_pct']} | "
            f"{r['viewer_frames_per_s'] if r['viewer_frames_per_s'] is not None else ''} | "
            f"{r['viewer_pose_events_per_s'] if r['viewer_pose_events_per_s'] is not None else ''} | "
            f"{r['jpeg_kb'] if r['jpeg_kb'] is not None else ''} | "
            f"{str(r['viewer_cpu_pct']) + ' %' if r['viewer_cpu_pct'] is not None else ''} |"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": rows, "encode_ms": encode_ms}, indent=2))


if __name__ == "__main__":
    main()
