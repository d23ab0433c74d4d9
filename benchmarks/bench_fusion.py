#!/usr/bin/env python3
"""Several cameras, one map: the fusion measured on the simulated wide arena.

    .venv/bin/python benchmarks/bench_fusion.py accuracy --work runs/fusion      # 4 cameras, 50 rovers, 300 frames
    .venv/bin/python benchmarks/bench_fusion.py live --work runs/fusion          # bridged brokers, real processes
    .venv/bin/python benchmarks/bench_fusion.py one-broker --work runs/fusion    # where the time goes, no bridges
    .venv/bin/python benchmarks/bench_fusion.py stages --work runs/fusion        # the fuser's work per message

``accuracy``: ``sim render wide`` (4 cameras, 50 rovers with one hue each: the simulator's palette spreads 50 hues
7.2 deg apart), every board calibrated from its own survey points (34, 0.5 px click noise), every video tracked
into detections (the real pipeline, ``track --detections``), fused offline (``edge-ips fuse``), compared with the
world's truth: accuracy overall, where two or more boards saw the rover and where one did; the jump at every
handover (the frame-to-frame change of the error when the set of boards that saw the rover changes) against the
same measure at other frames; swaps (a pose nearer another rover's truth than its own); the boards' clock
estimates against their true exposure offsets; the seams between the boards' calibrations; the fuser's CPU.

``live``: the same detections replayed in real time by four board processes, each with its own Mosquitto, and a
central Mosquitto that opens a bridge to each, as ``edge-ips broker-config --bridge`` writes them (the boards wait,
before publishing each frame, the time the tracker took for it in the accuracy run: so grab-to-pose covers tracking,
the board's broker, the bridge, the fuser and the central broker); two fusers (``edge-ips fuse --broker``);
``mosquitto_sub`` on the central broker and on a board's broker. Every board shows, at grab tick k, the same
recorded instant (:func:`replay_index`), stamped with its true grab time (its camera's exposure phase, a correct
clock). Measured: grab-to-fused-pose latency p50/p99 (receive time minus the pose's ``t``, the grab of the newest
detection in it; one clock, so a negative one is an error and counted), and the same for the detections at the
board's broker and at the central one (the bridge's share); the active fuser's CPU, the takeover time when the
active fuser is killed (and when it is paused), what happens when one board dies.

``stages``: the live fuser's Python work per detections message, no network: the recorded detections replayed as
the live boards send them (:func:`replay_index`, each board's exposure phase, Unix times), each message timed per
stage as :class:`edge.fusion.service.FuserService` runs them: parse (bytes to :class:`Detections`), fuse
(:meth:`Fuser.add` without learning), encode (each pose's bytes), learn (the clock aligner's share, after the poses
are out). The four boards' frames of one tick arrive together, so the last one's poses wait for the three before:
``last_of_tick_ms`` is the time from the tick's first message to the last one's poses encoded, the clocks learning
after each message; ``last_of_tick_learning_after_ms`` the same without the learning of the three before (the
service learns when no other message waits: after the burst). Also the clock
offsets the live fuser learned (against the fuser's clock, which is the boards' true clock here).

Timing figures (latency, CPU) measured on a loaded machine are not valid: re-run on a quiet one.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import os
import platform
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

PY = sys.executable


# -- accuracy --------------------------------------------------------------------------------------------------------
def render_and_track(work: Path, cameras: int, rovers: int, frames: int, seed: int) -> dict[str, Any]:
    """Render, calibrate and track every camera into ``work/camK/det.jsonl`` (and per-frame tracking times)."""
    from edge.offline import detection_builder, open_track_job
    from edge.sim.wide_export import render_wide_to_directory
    from edge.tracker_config import load_tracker_config

    out: dict[str, Any] = {}
    if not (work / "wide.json").is_file():
        t0 = time.perf_counter()
        summary = render_wide_to_directory(work, cameras=cameras, frames=frames, seed=seed, rovers=rovers)
        out["render_s"] = time.perf_counter() - t0
        out["render_ms_per_camera_frame"] = summary.render_ms_mean
        print(f"rendered {frames} frames x {cameras} cameras in {out['render_s']:.0f} s", flush=True)
    layout = json.loads((work / "wide.json").read_text())
    for cam in layout["cameras"]:
        where = work / cam["name"]
        cal = where / "calibration.json"
        if not cal.is_file():
            subprocess.run(
                [
                    PY,
                    "-m",
                    "edge.cli",
                    "calibrate",
                    "points",
                    str(where / "points.csv"),
                    "--out",
                    str(cal),
                    "--image",
                    str(where / "background.png"),
                ],
                check=True,
                capture_output=True,
                cwd=REPO,
            )
        det = where / "det.jsonl"
        if det.is_file():
            continue
        job = open_track_job(
            where / "video.mp4", cal, load_tracker_config(where / "rovers.toml"), where / "background.png"
        )
        times: list[float] = []
        t0 = time.perf_counter()
        job.run(
            det,
            on_frame=lambda r, times=times: times.append(r.stage_ms.get("total", 0.0)),  # type: ignore[misc]
            detections=detection_builder(job, cal, cam["name"]),
        )
        (where / "track_ms.json").write_text(json.dumps(times))
        print(f"tracked {cam['name']}: {len(times)} frames in {time.perf_counter() - t0:.0f} s", flush=True)
    return out


def _truth(work: Path) -> dict[tuple[int, str], tuple[float, float]]:
    with (work / "truth.csv").open() as f:
        return {(int(r["frame"]), r["id"]): (float(r["x"]), float(r["y"])) for r in csv.DictReader(f)}


def _visible(work: Path, names: list[str]) -> set[tuple[int, str]]:
    """Rover-frames some camera saw whole (a fused pose is due there)."""
    seen: set[tuple[int, str]] = set()
    for name in names:
        with (work / name / "visibility.csv").open() as f:
            for r in csv.DictReader(f):
                if float(r["visible"]) >= 0.999:
                    seen.add((int(r["frame"]), r["id"]))
    return seen


def _stats(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {"n": 0}
    return {"n": int(a.size), "mean": float(a.mean()), "p95": float(np.percentile(a, 95)), "max": float(a.max())}


def apparent_lags(work: Path, layout: dict[str, Any]) -> dict[str, float]:
    """Each camera's detections against the world at its own exposure instants: the error along the motion over
    the speed (s). The tracker's centroid trails a moving marker slightly; boards that differ in it look to the
    fuser like boards whose clocks differ by as much, and correcting for it is what aligns their measurements."""
    from edge.board_messages import parse_detections
    from edge.sim.wide import build_wide

    world = build_wide(len(layout["cameras"]), seed=layout["seed"], rovers=len(layout["rovers"])).world()
    out = {}
    for cam in layout["cameras"]:
        ve = vv = 0.0
        for line in (work / cam["name"] / "det.jsonl").read_bytes().splitlines():
            d = parse_detections(line)
            state = world.state_at(d.frame / layout["fps"] + cam["phase_s"]).by_id()
            for r in d.rovers:
                t = state[r.id]
                if math.hypot(r.x - t.x_cm, r.y - t.y_cm) > 5.0:
                    continue  # the board took another rover for this one: no timing in that
                ve += t.vx_cm_s * (r.x - t.x_cm) + t.vy_cm_s * (r.y - t.y_cm)
                vv += t.vx_cm_s**2 + t.vy_cm_s**2
        out[cam["name"]] = -ve / vv if vv else 0.0
    return out


def seam_figures(work: Path, layout: dict[str, Any]) -> dict[str, Any]:
    """``calibrate check`` across boards (check points clicked in both views), and the calibrations' own seam (the
    exact pixels of the same points mapped by both, no click noise)."""
    from edge.calibration.files import load_calibration
    from edge.calibration.points import read_points_csv
    from edge.camera import load_camera
    from edge.fusion.seams import check_boards, seams

    names = [c["name"] for c in layout["cameras"]]
    cals = {n: load_calibration(work / n / "calibration.json") for n in names}
    boards = [(work / n / "calibration.json", cals[n], read_points_csv(work / n / "check.csv")) for n in names]
    clicked = seams(check_boards(boards))
    exact = []
    for s in clicked:
        pts = np.column_stack([s.xy_world_cm, np.full(len(s.xy_world_cm), 13.0)])
        a = cals[s.a].pixel_to_world(load_camera(work / s.a / "camera.json").project(pts))
        b = cals[s.b].pixel_to_world(load_camera(work / s.b / "camera.json").project(pts))
        exact += list(np.linalg.norm(a - b, axis=1))
    return {
        "clicked": {f"{s.a}/{s.b}": {"n": s.n, "mean_cm": s.mean_cm, "max_cm": s.max_cm} for s in clicked},
        "calibrations": _stats(exact),
    }


def evaluate(work: Path) -> dict[str, Any]:
    from edge.fusion.offline import fuse_files

    layout = json.loads((work / "layout.json" if (work / "layout.json").exists() else work / "wide.json").read_text())
    names = [c["name"] for c in layout["cameras"]]
    truth = _truth(work)
    poses: list[Any] = []
    c0 = time.process_time()
    summary = fuse_files([work / n / "det.jsonl" for n in names], work / "fused.jsonl", on_pose=poses.append)
    cpu_s = time.process_time() - c0
    detections = sum(len(json.loads(line)["rovers"]) for n in names for line in (work / n / "det.jsonl").open())
    by_rover: dict[str, dict[int, tuple[float, float]]] = defaultdict(dict)
    for (frame, rid), xy in truth.items():
        by_rover[rid][frame] = xy
    errors, overlap, single, swaps = [], [], [], 0
    prev: dict[str, tuple[int, np.ndarray, tuple[str, ...]]] = {}
    handover, other = [], []
    for p in poses:
        t = truth.get((p.tick, p.rover_id))
        if t is None:
            continue
        e = np.array([p.x_cm - t[0], p.y_cm - t[1]])
        err = float(np.hypot(*e))
        errors.append(err)
        (overlap if len(p.boards) >= 2 else single).append(err)
        nearest = min(by_rover, key=lambda r: math.dist(by_rover[r].get(p.tick, (1e9, 1e9)), (p.x_cm, p.y_cm)))
        swaps += nearest != p.rover_id
        last = prev.get(p.rover_id)
        if last is not None and last[0] == p.tick - 1 and p.t_s > 1.0:
            jump = float(np.hypot(*(e - last[1])))
            (handover if set(last[2]) != set(p.boards) else other).append(jump)
        prev[p.rover_id] = (p.tick, e, p.boards)
    due = _visible(work, names)
    got = {(p.tick, p.rover_id) for p in poses}
    lags = apparent_lags(work, layout)
    offsets = {}
    for cam in layout["cameras"]:
        est = summary.offsets[cam["name"]]
        expected = -cam["phase_s"] + (lags[cam["name"]] - lags[names[0]])
        offsets[cam["name"]] = {
            "estimated_ms": 1e3 * est.offset_s,
            "sigma_ms": 1e3 * est.sigma_s,
            "exposure_offset_ms": -1e3 * cam["phase_s"],
            "apparent_lag_ms": 1e3 * lags[cam["name"]],
            "expected_ms": 1e3 * expected,
            "error_ms": 1e3 * (est.offset_s - expected),
        }
    return {
        "cameras": len(names),
        "rovers": len(layout["rovers"]),
        "frames": layout["frames"],
        "seed": layout["seed"],
        "poses": len(poses),
        "coverage": len(due & got) / max(len(due), 1),
        "accuracy_cm": _stats(errors),
        "two_or_more_boards_cm": _stats(overlap),
        "one_board_cm": _stats(single),
        "handover_jump_cm": _stats(handover) | {"p99": float(np.percentile(handover, 99)) if handover else 0.0},
        "other_frames_jump_cm": _stats(other) | {"p99": float(np.percentile(other, 99)) if other else 0.0},
        "swaps": swaps,
        "offsets": offsets,
        "seams": seam_figures(work, layout),
        "refused": {b: v["refused"] for b, v in summary.as_dict()["boards"].items()},
        "fuser_cpu": {
            "seconds": cpu_s,
            "per_message_ms": 1e3 * cpu_s / summary.frames,
            "per_detection_us": 1e6 * cpu_s / max(detections, 1),
            "messages": summary.frames,
            "detections": detections,
        },
    }


# -- live ------------------------------------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_mosquitto(conf: Path, workdir: Path, ports: dict[int, int]) -> subprocess.Popen[bytes]:
    """A Mosquitto from a ``broker-config`` file, every listener moved to the free port given for it."""
    lines = ["log_dest stderr"] + (["user root"] if os.geteuid() == 0 else [])
    for line in conf.read_text().splitlines():
        if line.startswith("listener "):
            parts = line.split()
            line = f"listener {ports[int(parts[1])]} 127.0.0.1"
        lines.append(line)
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "mosquitto.conf").write_text("\n".join(lines) + "\n")
    with (workdir / "log").open("wb") as log:  # the child keeps its own descriptor
        proc = subprocess.Popen(
            ["/usr/sbin/mosquitto", "-c", str(workdir / "mosquitto.conf")], stdout=subprocess.DEVNULL, stderr=log
        )
    port = next(iter(ports.values()))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"mosquitto did not start: {(workdir / 'log').read_text()}")


def replay_index(k: int, k0: int, frames: int) -> int:
    """The recorded frame a board shows at grab tick ``k`` when every board started at tick ``k0``: the same for
    every board (one world instant at one grab time), played forwards then backwards (no rover teleports at the
    loop's end: a board counting its own frames from its own start would show each board another instant)."""
    if frames < 2:
        return 0
    j = (k - k0) % (2 * frames - 2)
    return j if j < frames else 2 * frames - 2 - j


def replay_board(url: str, edge_id: str, det_path: Path, times_path: Path, k0: int, phase_s: float) -> None:
    """A board: its recorded detections in real time. Frame ``k`` of the shared clock is grabbed at ``k / 30 +
    phase_s`` of the wall clock (the camera's exposure phase in the recording; a correct clock, so the pose's ``t``
    is a grab time on the subscriber's clock), shows recorded frame :func:`replay_index` ``(k, k0)``, and is
    published after the tracking time that frame took in the accuracy run."""
    from urllib.parse import urlsplit

    import paho.mqtt.client as mqtt

    from edge.board_messages import detections_topic, parse_detections
    from edge.fusion.detections import encode_detections, from_message
    from edge.messages import StatusV1, dumps, edge_status_topic

    frames = [from_message(parse_detections(line)) for line in det_path.read_bytes().splitlines()]
    track_ms = json.loads(times_path.read_text()) if times_path.name != "none" else [0.0] * len(frames)
    target = urlsplit(url)
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"edge-ips-{edge_id}")
    client.username_pw_set(target.username, target.password)
    offline = StatusV1(v=1, edge=edge_id, state="offline", camera="stopped", fps=0.0, rovers=[], missing=[], t=0.0)
    client.will_set(edge_status_topic(edge_id), dumps(offline), qos=1, retain=True)
    client.on_socket_open = lambda c, u, s: s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    client.connect(target.hostname or "127.0.0.1", target.port or 1883)
    client.loop_start()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda s, f: stop.set())
    k = max(k0, math.ceil((time.time() - phase_s) * 30.0))
    n = 0
    while not stop.is_set():
        grab = k / 30.0 + phase_s
        i = replay_index(k, k0, len(frames))
        due = grab + track_ms[i] / 1e3
        wait = due - time.time()
        if wait > 0:
            stop.wait(wait)
        d = frames[i]
        moved = type(d)(edge_id, n, k, grab, time.time(), d.image_quality, d.view_cm, d.rovers)
        client.publish(detections_topic(edge_id), encode_detections(moved), qos=0)
        if n % 30 == 0:
            online = StatusV1(
                v=1, edge=edge_id, state="online", camera="ok", fps=30.0, rovers=[], missing=[], t=round(time.time(), 3)
            )
            client.publish(edge_status_topic(edge_id), dumps(online), qos=1, retain=True)
        n += 1
        k = max(k + 1, math.floor((time.time() - phase_s) * 30.0))  # a board that falls behind skips frames
    client.disconnect()
    client.loop_stop()


class Subscriber:
    """Receive times of the fusers' and boards' statuses on a broker, and of what :meth:`add` asks for later."""

    def __init__(self, port: int, user: str, password: str) -> None:
        import paho.mqtt.client as mqtt

        self.messages: list[tuple[float, str, bytes]] = []
        self.lock = threading.Lock()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"edge-ips-bench-{port}")
        self.client.username_pw_set(user, password)
        # statuses first; the poses once the latency is timed (1500 a second into Python load the machine timed)
        self.topics = ["ips/v1/fuser/#", "ips/v1/edge/+/status"]
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe([(t, 0) for t in self.topics])
        self.client.on_message = self._on_message
        self.client.on_socket_open = lambda c, u, s: s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def _on_message(self, c: Any, u: Any, m: Any) -> None:
        now = time.time()
        with self.lock:
            self.messages.append((now, m.topic, bytes(m.payload)))

    def add(self, topic: str) -> None:
        self.topics.append(topic)
        self.client.subscribe(topic, qos=0)

    def since(self, t: float) -> list[tuple[float, str, bytes]]:
        with self.lock:
            return [m for m in self.messages if m[0] >= t]

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


class CSubscriber:
    """``mosquitto_sub`` on a broker, every pose and detections message with its receive time (``%U``) in a file."""

    def __init__(self, port: int, user: str, password: str, out: Path) -> None:
        self.out = out
        with out.open("wb") as f:
            self.proc = subprocess.Popen(
                [
                    "mosquitto_sub", "-h", "127.0.0.1", "-p", str(port), "-u", user, "-P", password,
                    "-t", "ips/v1/rovers/+/pose", "-t", "ips/v1/edge/+/detections", "-F", "%U %t %p",
                ],
                stdout=f,
            )  # fmt: skip

    def stop(self) -> list[tuple[float, str, bytes]]:
        self.proc.terminate()
        self.proc.wait(10)
        out = []
        for line in self.out.read_bytes().splitlines():
            t, topic, payload = line.split(b" ", 2)
            out.append((float(t), topic.decode(), payload))
        return out


def _poses(messages: list[tuple[float, str, bytes]]) -> list[tuple[float, Any]]:
    from edge.messages import parse_pose

    return [(t, parse_pose(p)) for t, topic, p in messages if topic.endswith("/pose")]


def _detection_ages(messages: list[tuple[float, str, bytes]], edge_id: str | None) -> list[float]:
    """Receive time minus grab time (ms) of the detections of ``edge_id`` (None: every board's)."""
    from edge.board_messages import detections_topic, parse_detections

    wanted = detections_topic(edge_id) if edge_id is not None else None
    return [
        1e3 * (t - parse_detections(p).t)
        for t, topic, p in messages
        if topic.endswith("/detections") and (wanted is None or topic == wanted)
    ]


def latency_stats(latencies_ms: list[float]) -> dict[str, float]:
    """p50 / p99 / max of receive-minus-grab times. A negative one is not fast but wrong: the times it subtracts are
    on two clocks (a board replaying another instant than the others, a pose dated after it left); counted."""
    if not latencies_ms:
        return {"n": 0}
    a = np.asarray(latencies_ms)
    negative = int((a < 0.0).sum())
    if negative:
        print(f"WARNING: {negative} of {a.size} latencies negative (min {a.min():.1f} ms): two clocks", flush=True)
    return {
        "n": int(a.size),
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
        "min": float(a.min()),
        "negative": negative,
    }


def _fuser_state(messages: list[tuple[float, str, bytes]]) -> dict[str, str]:
    from edge.board_messages import parse_fuser_status

    out = {}
    for _, topic, p in messages:
        if topic.startswith("ips/v1/fuser/") and topic.endswith("/status"):
            s = parse_fuser_status(p)
            out[s.fuser] = s.state
    return out


def _wait(predicate: Any, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def live(work: Path, seconds: float, repeats: int, tracking_delay: bool = True) -> dict[str, Any]:
    import psutil

    from edge.broker.bridge import BoardAddress, read_logins, write_bridge_configs

    layout = json.loads((work / "wide.json").read_text())
    names = [c["name"] for c in layout["cameras"]]
    brokers = work / "brokers"
    if brokers.exists():
        import shutil

        shutil.rmtree(brokers)
    # every listener on a free loopback port; the central broker opens a bridge to each board's network listener
    board_ports = {name: {1884: free_port(), 1883: free_port()} for name in names}
    write_bridge_configs(
        brokers,
        boards={name: BoardAddress("127.0.0.1", board_ports[name][1883]) for name in names},
        rovers=[],
        fusers=["fuser-a", "fuser-b"],
    )

    def logins(where: Path) -> dict[str, dict[str, str]]:
        return read_logins(where / "credentials.toml")

    central_logins = logins(brokers / "central")
    central_ports = {1884: free_port(), 1883: free_port()}
    procs: list[subprocess.Popen[Any]] = [
        start_mosquitto(brokers / name / "mosquitto.conf", work / "run" / name, board_ports[name]) for name in names
    ]
    procs.append(start_mosquitto(brokers / "central" / "mosquitto.conf", work / "run" / "central", central_ports))
    results: dict[str, Any] = {}
    try:
        at_central = Subscriber(central_ports[1884], "edge", central_logins["edge"]["edge"])
        board1 = logins(brokers / names[0])
        boards = {}
        k0 = math.ceil((time.time() + 3.0) * 30.0)  # every board's first frame: one world instant, one grab time
        phases = {c["name"]: c["phase_s"] for c in layout["cameras"]}
        for name in names:
            url = f"mqtt://edge:{logins(brokers / name)['edge']['edge']}@127.0.0.1:{board_ports[name][1884]}"
            boards[name] = subprocess.Popen(
                [
                    PY,
                    __file__,
                    "_board",
                    url,
                    name,
                    str(work / name / "det.jsonl"),
                    str(work / name / "track_ms.json") if tracking_delay else "none",
                    str(k0),
                    repr(phases[name]),
                ],
                cwd=REPO,
            )
        fusers = {}

        def start_fuser(fid: str) -> subprocess.Popen[Any]:
            url = f"mqtt://{fid}:{central_logins['fusers'][fid]}@127.0.0.1:{central_ports[1883]}"
            return subprocess.Popen(
                [PY, "-m", "edge.cli", "fuse", "--broker", url, "--id", fid],
                cwd=REPO,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )

        for fid in ("fuser-a", "fuser-b"):
            fusers[fid] = start_fuser(fid)
        if not _wait(lambda: "active" in _fuser_state(at_central.since(0)).values(), 60):
            raise RuntimeError("no fuser became active")
        time.sleep(5.0)  # let the clock estimates settle
        # -- latency and CPU ------------------------------------------------------------------------------------
        active = next(f for f, s in _fuser_state(at_central.since(0)).items() if s == "active")
        proc = psutil.Process(fusers[active].pid)
        # the latency is timed by mosquitto_sub (C): the Python subscribers' own queue is not the system's
        timers = {
            "central": CSubscriber(central_ports[1884], "edge", central_logins["edge"]["edge"], work / "run" / "c.txt"),
            "board": CSubscriber(board_ports[names[0]][1884], "edge", board1["edge"]["edge"], work / "run" / "b.txt"),
        }
        time.sleep(1.0)
        t0 = time.time()
        cpu0 = proc.cpu_times()
        time.sleep(seconds)
        cpu1 = proc.cpu_times()
        t1 = time.time()
        cpu = (cpu1.user + cpu1.system - cpu0.user - cpu0.system) / (t1 - t0)
        central = [m for m in timers["central"].stop() if t0 <= m[0] <= t1]
        board = [m for m in timers["board"].stop() if t0 <= m[0] <= t1]
        lat_c = [1e3 * (t - p.t) for t, p in _poses(central)]
        results["latency_central_ms"] = latency_stats(lat_c)
        results["latency_board_ms"] = latency_stats([1e3 * (t - p.t) for t, p in _poses(board)])
        # where the time goes: a grab to its detections on the board's broker, and through the bridge to the central
        results["detections_at_board_ms"] = latency_stats(_detection_ages(board, names[0]))
        results["detections_at_central_ms"] = latency_stats(_detection_ages(central, None))
        results["fuser_cpu_percent"] = 100.0 * cpu
        results["poses_per_s"] = len(lat_c) / (t1 - t0)
        at_central.add("ips/v1/rovers/+/pose")
        # -- takeover -------------------------------------------------------------------------------------------
        takeovers: dict[str, list[float]] = {"killed": [], "paused": []}
        for how in ("killed", "paused"):
            for _ in range(repeats):
                states = _fuser_state(at_central.since(0))
                holder = next(f for f, s in states.items() if s == "active")
                other = "fuser-b" if holder == "fuser-a" else "fuser-a"
                t_cut = time.time()
                if how == "killed":
                    fusers[holder].kill()
                    fusers[holder].wait()
                else:
                    os.kill(fusers[holder].pid, signal.SIGSTOP)
                ok = _wait(
                    lambda t_cut=t_cut, other=other: (  # type: ignore[misc]
                        any(t > t_cut for t, _ in _poses(at_central.since(t_cut)))
                        and _fuser_state(at_central.since(t_cut)).get(other) == "active"
                    ),
                    10,
                )
                time.sleep(1.0)
                # the rovers' view of it: the longest silence in the pose stream around the cut
                times = sorted(t for t, _ in _poses(at_central.since(t_cut - 0.5)) if t <= t_cut + 2.0)
                silence = max((b - a for a, b in itertools.pairwise(times)), default=math.nan)
                takeovers[how].append(silence if ok else math.nan)
                if how == "killed":
                    fusers[holder] = start_fuser(holder)
                else:
                    os.kill(fusers[holder].pid, signal.SIGCONT)
                _wait(
                    lambda: sorted(_fuser_state(at_central.since(time.time() - 3)).values()) == ["active", "standby"],
                    20,
                )
                time.sleep(2.0)
        results["takeover_s"] = {
            k: {"runs": v, "max": float(np.nanmax(v)) if v else None} for k, v in takeovers.items()
        }
        # -- a board dies ---------------------------------------------------------------------------------------
        dead = names[-1]
        t_kill = time.time()
        boards[dead].kill()
        from edge.board_messages import parse_fuser_status

        def dead_reported() -> bool:
            for _, topic, p in reversed(at_central.since(t_kill)):
                if topic.startswith("ips/v1/fuser/") and topic.endswith("/status"):
                    s = parse_fuser_status(p)
                    if s.state == "active":
                        return any(b.edge == dead and b.state != "ok" for b in s.boards)
            return False

        _wait(dead_reported, 20)
        t_reported = time.time()
        time.sleep(3.0)
        after = at_central.since(t_reported + 1.0)
        status = next(
            parse_fuser_status(p)
            for _, topic, p in reversed(after)
            if topic.endswith("/status")
            and topic.startswith("ips/v1/fuser/")
            and parse_fuser_status(p).state == "active"
        )
        before = {p.id for _, p in _poses(at_central.since(t_kill - 3.0)) if _ <= t_kill}
        still = {p.id for _, p in _poses(after)}
        (board,) = [b for b in status.boards if b.edge == dead]
        results["board_dies"] = {
            "board": dead,
            "reported_after_s": t_reported - t_kill,
            "state": board.state,
            "view_reported": board.view,
            "rovers_before": len(before),
            "rovers_still_posed": len(still),
            "missing": status.missing,
        }
        at_central.stop()
        for p in [*boards.values(), *fusers.values()]:
            if p.poll() is None:
                p.terminate()
                p.wait(10)
    finally:
        for p in procs:
            p.terminate()
            p.wait(10)
    return results


def one_broker(work: Path, seconds: float) -> dict[str, Any]:
    """Where the time goes, without bridges: the four replayed boards (no tracking delay) on one Mosquitto and the
    fuser in this process, timed at its publish (the pose's age then), per detections message (parse, fuse,
    publish), and at ``mosquitto_sub``."""
    from edge.config import parse_broker_url
    from edge.fusion.service import FuserService

    layout = json.loads((work / "wide.json").read_text())
    run = work / "run" / "one-broker"
    run.mkdir(parents=True, exist_ok=True)
    port = free_port()
    (run / "mosquitto.conf").write_text(
        f"listener {port} 127.0.0.1\nallow_anonymous true\nset_tcp_nodelay true\npersistence false\n"
    )
    broker = subprocess.Popen(["/usr/sbin/mosquitto", "-c", str(run / "mosquitto.conf")], stderr=subprocess.DEVNULL)
    ages: list[float] = []
    per_message: list[float] = []
    service = FuserService(
        parse_broker_url(f"mqtt://127.0.0.1:{port}"), "f1", on_pose=lambda p, line: ages.append(time.time() - p.t_s)
    )
    fuse = service._fuse

    def timed(payload: bytes) -> None:
        t = time.perf_counter()
        fuse(payload)
        per_message.append(time.perf_counter() - t)

    service._fuse = timed  # type: ignore[method-assign]
    boards: list[subprocess.Popen[bytes]] = []
    try:
        _wait(lambda: socket.socket().connect_ex(("127.0.0.1", port)) == 0, 10)
        service.start()
        service.wait_connected(10)
        k0 = math.ceil((time.time() + 2.0) * 30.0)
        for cam in layout["cameras"]:
            det = str(work / cam["name"] / "det.jsonl")
            args = [PY, __file__, "_board", f"mqtt://x:y@127.0.0.1:{port}", cam["name"], det, "none", str(k0)]
            boards.append(subprocess.Popen([*args, repr(cam["phase_s"])], cwd=REPO))
        time.sleep(6.0)
        timer = CSubscriber(port, "x", "y", run / "sub.txt")
        time.sleep(1.0)
        ages.clear()
        per_message.clear()
        t0 = time.time()
        time.sleep(seconds)
        t1 = time.time()
        got = [m for m in timer.stop() if t0 <= m[0] <= t1]
        return {
            "pose_age_at_publish_ms": latency_stats([1e3 * a for a in ages]),
            "fuser_per_message_ms": latency_stats([1e3 * a for a in per_message]),
            "latency_ms": latency_stats([1e3 * (t - p.t) for t, p in _poses(got)]),
            "detections_at_broker_ms": latency_stats(_detection_ages(got, None)),
        }
    finally:
        for b in boards:
            b.terminate()
        service.stop()
        broker.terminate()


def stages(work: Path, seconds: float, latency_s: float = 0.002) -> dict[str, Any]:
    """The fuser's work per detections message, per stage (see the module's doc)."""
    from edge.board_messages import parse_detections
    from edge.fusion.core import Fuser
    from edge.fusion.detections import Detections, encode_detections, from_message
    from edge.fusion.offline import pose_line

    layout = json.loads((work / "wide.json").read_text())
    cams = sorted(layout["cameras"], key=lambda c: c["phase_s"])
    recorded = {
        c["name"]: [
            from_message(parse_detections(x)) for x in (work / c["name"] / "det.jsonl").read_bytes().splitlines()
        ]
        for c in cams
    }
    t0 = 1.8e9  # Unix times, as live: the wire's rounding of large numbers
    ticks = []
    for k in range(round(seconds * 30.0)):
        tick = []
        for c in cams:
            d = recorded[c["name"]][replay_index(k, 0, len(recorded[c["name"]]))]
            grab = t0 + k / 30.0 + c["phase_s"]
            moved = Detections(d.edge_id, k, k, grab, grab, d.image_quality, d.view_cm, d.rovers)
            tick.append((encode_detections(moved), grab + latency_s))
        ticks.append(tick)
    fuser = Fuser()
    names = ("parse", "fuse", "encode", "learn", "total")
    # wall time (what a pose waits) and the thread's CPU time (the same work, without the waits a loaded machine adds)
    clocks = {"wall": time.perf_counter, "cpu": time.thread_time}
    ms: dict[str, dict[str, list[float]]] = {c: {n: [] for n in names} for c in clocks}
    last_of_tick: dict[str, list[float]] = {c: [] for c in clocks}
    burst: dict[str, list[float]] = {c: [] for c in clocks}  # the same, the clocks learning after the tick's frames
    warmup = 30  # the first second: tracks and clocks starting

    def now() -> tuple[float, float]:
        return time.perf_counter(), time.thread_time()

    for k, tick in enumerate(ticks):
        start = now()
        learning = [0.0, 0.0]
        for payload, arrival in tick:
            a = now()
            d = from_message(parse_detections(payload))
            b = now()
            poses = fuser.add(d, now_s=arrival, learn=False)
            c = now()
            for n, pose in enumerate(poses):
                pose_line(pose, n)
            e = now()
            fuser.learn_pending()
            f = now()
            learning = [learning[0] + f[0] - e[0], learning[1] + f[1] - e[1]]
            if k >= warmup:
                for i, clock in enumerate(clocks):
                    for name, v in zip(
                        names, (b[i] - a[i], c[i] - b[i], e[i] - c[i], f[i] - e[i], f[i] - a[i]), strict=True
                    ):
                        ms[clock][name].append(1e3 * v)
        if k >= warmup:
            for i, clock in enumerate(clocks):
                last_of_tick[clock].append(1e3 * (e[i] - start[i]))
                burst[clock].append(1e3 * (e[i] - start[i] - (learning[i] - (f[i] - e[i]))))
    offsets = fuser.aligner.estimates()
    return {
        "messages": len(ms["wall"]["total"]),
        "stages_ms": {c: {n: _spread(v) for n, v in by_stage.items()} for c, by_stage in ms.items()},
        "last_of_tick_ms": {c: _spread(v) for c, v in last_of_tick.items()},
        "last_of_tick_learning_after_ms": {c: _spread(v) for c, v in burst.items()},
        # live, the offsets are against the fuser's clock: the boards' clocks are exact, so the truth is 0 less the
        # latency the arrival bound cannot see, plus each board's apparent lag (its tracker's smoothing)
        "offsets_ms": {
            b: {"offset": 1e3 * o.offset_s, "sigma": 1e3 * o.sigma_s, "source": o.source} for b, o in offsets.items()
        },
    }


def _spread(values: list[float]) -> dict[str, float]:
    a = np.asarray(values)
    return {
        "n": int(a.size),
        "mean": float(a.mean()),
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    sub = parser.add_subparsers(dest="what", required=True)
    acc = sub.add_parser("accuracy")
    acc.add_argument("--work", type=Path, required=True)
    acc.add_argument("--cameras", type=int, default=4)
    acc.add_argument("--rovers", type=int, default=50)
    acc.add_argument("--frames", type=int, default=300)
    acc.add_argument("--seed", type=int, default=1)
    acc.add_argument(
        "--detections-only",
        action="store_true",
        help="Fuse and evaluate the detections --work already holds (a changed fuser on the same recording).",
    )
    lv = sub.add_parser("live")
    lv.add_argument("--work", type=Path, required=True)
    lv.add_argument("--seconds", type=float, default=30.0)
    lv.add_argument("--repeats", type=int, default=5)
    lv.add_argument(
        "--no-tracking-delay",
        dest="tracking_delay",
        action="store_false",
        help="Publish each frame at its grab time: the latency of the brokers, bridges and fuser alone.",
    )
    one = sub.add_parser("one-broker")
    one.add_argument("--work", type=Path, required=True)
    one.add_argument("--seconds", type=float, default=20.0)
    st = sub.add_parser("stages")
    st.add_argument("--work", type=Path, required=True)
    st.add_argument("--seconds", type=float, default=60.0)
    board = sub.add_parser("_board")
    board.add_argument("args", nargs=6)
    a = parser.parse_args()
    if a.what == "_board":
        url, edge_id, det, times, k0, phase = a.args
        replay_board(url, edge_id, Path(det), Path(times), int(k0), float(phase))
        return
    print(f"# {platform.node()} {platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M')}")
    if a.what == "accuracy":
        a.work.mkdir(parents=True, exist_ok=True)
        if a.detections_only:
            if not (a.work / "truth.csv").exists():
                parser.error(f"{a.work} holds no recording (truth.csv): run without --detections-only first")
            extra: dict[str, Any] = {}
        else:
            extra = render_and_track(a.work, a.cameras, a.rovers, a.frames, a.seed)
        result = evaluate(a.work) | extra
        (a.work / "accuracy.json").write_text(json.dumps(result, indent=2))
    elif a.what == "stages":
        result = stages(a.work, a.seconds)
        (a.work / "stages.json").write_text(json.dumps(result, indent=2))
    elif a.what == "one-broker":
        result = one_broker(a.work, a.seconds)
        (a.work / "one-broker.json").write_text(json.dumps(result, indent=2))
    else:
        result = live(a.work, a.seconds, a.repeats, a.tracking_delay) | {"tracking_delay": a.tracking_delay}
        name = "live.json" if a.tracking_delay else "live-transport.json"
        (a.work / name).write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
