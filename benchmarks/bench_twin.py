"""The live twin, measured with real processes: ``edge-ips sim twin`` (the lab) and ``edge-ips start --source
sim:twin`` (the appliance, embedded broker), an MQTT observer reading the poses as published.

Two measurements:

* ``run``: one recorded run (``start --record``) of the paper's three formations through the dashboard's HTTP API,
  each judged on the published poses by the closed-loop bar (converged by frame 240?), each followed by a scatter
  and a STOP while the rovers drive (how far each moved from 0.5 s to 1.5 s after it); the pose latency from the
  frame reaching the edge to the observer (tracking, publishing, the broker) and its jitter; ``edge-ips plot`` of
  the recording. ``--out DIR`` keeps the recording, ``run.json`` and ``twin_run.png``.
* ``cpu``: for each fleet size (``--rovers 3,6,9,12``), the CPU time of the lab and of the edge over ``--seconds``
  while the rovers drive a rendezvous (scattered every 8 s), and the cost of one more rover (the slope).
  ``--cameras N`` (2-4): the lab over the wide arena with N cameras, one ``edge-ips start --source sim:twin:camK``
  per camera publishing detections and ``edge-ips fuse``, on a private Mosquitto: the CPU of each camera's
  rendering, each board and the fuser, each camera's frame rate, the fused poses' latency.

Timing figures (latency, CPU) are only meaningful on a quiet machine. Example::

    python benchmarks/bench_twin.py run --out runs/twin [--repeat 5]
    python benchmarks/bench_twin.py cpu --rovers 3,6,9,12 --seconds 30
    python benchmarks/bench_twin.py cpu --cameras 2 --rovers 3 --seconds 30
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks._common import MOSQUITTO_BENCH, free_port, private_mosquitto  # noqa: E402
from edge.messages import FORMATION_TOPIC, POSE_WILDCARD  # noqa: E402
from edge.sim.twin.bars import largest_moves_cm, score_formation  # noqa: E402
from edge.sim.twin.source import LabClient  # noqa: E402

EDGE_IPS = [sys.executable, "-m", "edge.cli"]
TOKEN = "bench-twin-token"
FRAMES = 300
HZ = os.sysconf("SC_CLK_TCK")


def _env(state: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    return {**env, "PYTHONPATH": str(ROOT), "EDGE_IPS_EDGE__STATE_DIR": str(state), **extra}


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / HZ  # utime + stime of the process (all its threads)


def _wait(what: str, ready: Any, timeout_s: float = 300.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        if time.monotonic() > deadline:
            raise SystemExit(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.2)


class Observer:
    """Every pose and formation message the broker delivers, with when it arrived."""

    def __init__(self, port: int) -> None:
        self.poses: list[dict[str, Any]] = []
        self.formations: list[tuple[float, dict[str, Any]]] = []
        self._lock = threading.Lock()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-twin-observer")
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe([(POSE_WILDCARD, 0), (FORMATION_TOPIC, 1)])
        self.client.on_message = self._message
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def _message(self, c: Any, u: Any, m: mqtt.MQTTMessage) -> None:
        now = time.time()
        doc = json.loads(m.payload) if m.payload else None
        with self._lock:
            if m.topic == FORMATION_TOPIC and doc is not None:
                self.formations.append((now, doc))
            elif doc is not None:
                self.poses.append({**doc, "t_recv": now})

    def since(self, t: float) -> list[dict[str, Any]]:
        with self._lock:
            return [p for p in self.poses if p["t"] >= t]

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@dataclass
class Fleet:
    """A lab's controls, the dashboard that commands its rovers, the observer of their poses."""

    lab: LabClient
    http_port: int
    observer: Observer
    ids: list[str]

    def command(self, kind: str) -> dict[str, Any]:
        body = json.dumps({"kind": kind, "ids": self.ids if kind != "stop" else []}).encode()
        request = urllib.request.Request(
            f"http://127.0.0.1:{self.http_port}/api/formation",
            data=body,
            headers={"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"},
            method="POST",
        )
        with urllib.request.urlopen(request, timeout=30) as reply:
            return dict(json.loads(reply.read())["formation"])

    def scatter_and_track(self) -> float:
        t = time.time()
        self.lab.scatter()

        def tracked() -> bool:
            recent = self.observer.since(t)
            return all(sum(p["id"] == r for p in recent) > 30 for r in self.ids)

        _wait("every rover tracked after a scatter", tracked)
        return t


@dataclass
class Twin(Fleet):
    """One camera: the edge, and the lab when it was started by hand."""

    edge: subprocess.Popen[bytes]
    lab_process: subprocess.Popen[bytes] | None = None


def _healthy(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=2) as reply:
            return bool(reply.status == 200)
    except OSError:
        return False


@contextmanager
def twin(workdir: Path, rovers: int, record: Path | None) -> Iterator[Twin]:
    """A lab of ``rovers`` (started by hand unless 3) and an edge tracking it, on the embedded broker."""
    state = workdir / "s"
    broker, http = free_port(), free_port()
    lab_process = None
    env = _env(state, EDGE_IPS_BROKER__EMBEDDED_PORT=str(broker), EDGE_IPS_DASHBOARD__TOKEN=TOKEN)
    if rovers != 3:  # the edge starts a 3-rover lab by itself; other sizes are started by hand, as a user would
        lab_args = ["sim", "twin", "--rovers", str(rovers), "--broker", f"mqtt://127.0.0.1:{broker}"]
        lab_args += ["--credentials", str(state / "broker-credentials.toml"), "--wait-for-logins"]
        with (workdir / "lab.log").open("wb") as out:
            lab_process = subprocess.Popen([*EDGE_IPS, *lab_args], env=env, stdout=out, stderr=out)
        lab = LabClient(state / "twin.sock")
        _wait("the lab", lambda: _answers(lab))
    args = ["start", "--source", "sim:twin", "--http-port", str(http)]
    if record is not None:
        args += ["--record", str(record)]
    with (workdir / "edge.log").open("wb") as out:
        edge = subprocess.Popen([*EDGE_IPS, *args], env=env, stdout=out, stderr=out, cwd=workdir)
    try:
        _wait("the edge online", lambda: _healthy(http))
        lab = LabClient(state / "twin.sock")
        ids = [r["id"] for r in lab.status()["rovers"]]
        observer = Observer(broker)
        try:
            yield Twin(lab, http, observer, ids, edge, lab_process)
        finally:
            observer.close()
    finally:
        edge.send_signal(signal.SIGTERM)
        edge.wait(60)
        if lab_process is not None:
            lab_process.send_signal(signal.SIGINT)
            lab_process.wait(60)


def _answers(lab: LabClient) -> bool:
    try:
        lab.status()
    except Exception:
        return False
    return True


def _latency(poses: list[dict[str, Any]]) -> dict[str, float]:
    """From the frame reaching the edge (the pose's ``t``) to the observer: ms."""
    ms = np.array([1000.0 * (p["t_recv"] - p["t"]) for p in poses])
    p50, p95, p99 = np.percentile(ms, [50, 95, 99])
    return {
        "n": int(ms.size),
        "p50": round(float(p50), 1),
        "p95": round(float(p95), 1),
        "p99": round(float(p99), 1),
        "max": round(float(ms.max()), 1),
        "jitter_std": round(float(ms.std()), 1),
    }


def _formation(t: Twin, kind: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """Scatter, command ``kind``, judge its frames; scatter again and STOP while the rovers drive back."""
    t.scatter_and_track()
    seq = t.command(kind)["seq"]
    _wait(f"{kind} delivered", lambda: any(d.get("seq") == seq for _, d in t.observer.formations))
    t_cmd = next(tr for tr, d in t.observer.formations if d.get("seq") == seq)

    def enough() -> bool:
        frames = [p["frame"] for p in t.observer.since(t_cmd)]
        return bool(frames) and max(frames) - min(frames) >= FRAMES

    _wait(f"{FRAMES} frames", enough)
    poses = t.observer.since(t_cmd)
    score = asdict(score_formation(poses, t.ids, kind, min(p["frame"] for p in poses), FRAMES))
    t.scatter_and_track()
    _wait("driving", lambda: any(np.hypot(p["vx"], p["vy"]) > 10 for p in t.observer.since(time.time() - 1)))
    t_stop = time.time()
    t.command("stop")
    _wait("poses after the stop", lambda: bool(t.observer.since(t_stop + 1.6)))
    moved = largest_moves_cm(t.observer.since(t_stop), t.ids, t_stop + 0.5, t_stop + 1.5)
    return score, {"after": kind, "moved_cm": {r: round(v, 2) for r, v in moved.items()}}


def run(out: Path, repeat: int) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    record = out / "recording"
    if record.is_dir() and any(record.iterdir()):  # the plot reads every recording file there: one run's only
        raise SystemExit(f"{record} holds an earlier run's recording: give another --out or remove it")
    results: dict[str, Any] = {"formations": [], "stops": []}
    with tempfile.TemporaryDirectory(prefix="twin-") as tmp, twin(Path(tmp), 3, record) as t:
        t0 = time.time()
        for kind in ("line", "rendezvous", "triangle") * repeat:
            score, stop = _formation(t, kind)
            results["formations"].append(score)
            results["stops"].append(stop)
            print(f"{kind}: {score}; stop: {stop}", file=sys.stderr)
        results["latency_ms"] = _latency(t.observer.since(t0))
        status = t.lab.status()
        results["camera"] = status["camera"]
        results["air_delay_ms"] = {r["id"]: r["pose_delay_ms"] for r in status["rovers"]}
    png = out / "twin_run.png"
    done = subprocess.run(
        [*EDGE_IPS, "plot", str(record), "--out", str(png), "--title", "the live twin: line, rendezvous, triangle"],
        env=_env(out / "s"),
        capture_output=True,
        text=True,
    )
    results["plot"] = done.stdout.strip() or done.stderr.strip()
    (out / "run.json").write_text(json.dumps(results, indent=2) + "\n")
    return results


def cpu(sizes: list[int], seconds: float) -> list[dict[str, Any]]:
    rows = []
    for n in sizes:
        with tempfile.TemporaryDirectory(prefix=f"twin-{n}-") as tmp, twin(Path(tmp), n, None) as t:
            lab_pid = t.lab_process.pid if t.lab_process is not None else _child_lab(t.edge.pid)
            t.command("rendezvous")
            t.scatter_and_track()
            c0 = (_cpu_s(lab_pid), _cpu_s(t.edge.pid), time.monotonic())
            before = t.lab.status()
            s0 = before["camera"]
            last_scatter = time.monotonic()
            while time.monotonic() - c0[2] < seconds:
                time.sleep(0.5)
                if time.monotonic() - last_scatter > 8.0:
                    t.lab.scatter()
                    last_scatter = time.monotonic()
            wall = time.monotonic() - c0[2]
            lab_cpu, edge_cpu = (_cpu_s(lab_pid) - c0[0]) / wall, (_cpu_s(t.edge.pid) - c0[1]) / wall
            after = t.lab.status()
            s1 = after["camera"]
            frames = s1["frames"] - s0["frames"]
            parts = _parts_pct(before["cpu_s"], after["cpu_s"], wall)
            rows.append(
                {
                    "rovers": n,
                    "lab_cpu_pct": round(100 * lab_cpu, 1),
                    "edge_cpu_pct": round(100 * edge_cpu, 1),
                    "camera_fps": round(frames / wall, 1),
                    "frames_skipped": s1["skipped"] - s0["skipped"],
                    "latency_ms": _latency(t.observer.since(time.time() - wall)),
                    "lab_parts_pct": parts,
                }
            )
            print(rows[-1], file=sys.stderr)
    if len(rows) > 1:
        fleet = np.array([r["rovers"] for r in rows], dtype=float)
        total = np.array([r["lab_cpu_pct"] + r["edge_cpu_pct"] for r in rows])
        lab = np.array([r["lab_cpu_pct"] for r in rows])
        edge = np.array([r["edge_cpu_pct"] for r in rows])
        for row in rows:
            row["per_rover_pct"] = {
                "total": round(float(np.polyfit(fleet, total, 1)[0]), 2),
                "lab": round(float(np.polyfit(fleet, lab, 1)[0]), 2),
                "edge": round(float(np.polyfit(fleet, edge, 1)[0]), 2),
            }
    return rows


def _parts_pct(before: dict[str, Any], after: dict[str, Any], wall_s: float) -> dict[str, float]:
    """What the lab's threads used over the window, % of one core: rendering, physics, and per rover (mean) its
    firmware and its link's relay (the lab's own per-thread CPU clocks: valid when the machine is busy too)."""

    def pct(a: float, b: float) -> float:
        return round(100.0 * (b - a) / wall_s, 2)

    rovers = after["rovers"]
    firmware = [pct(before["rovers"][r]["firmware"], rovers[r]["firmware"]) for r in rovers]
    link = [pct(before["rovers"][r]["link"], rovers[r]["link"]) for r in rovers]
    return {
        "camera": pct(before["camera"], after["camera"]),
        "physics": pct(before["physics"], after["physics"]),
        "firmware_per_rover": round(float(np.mean(firmware)), 2),
        "link_per_rover": round(float(np.mean(link)), 2),
    }


def _child_lab(edge_pid: int) -> int:
    """The lab the edge started (its child running `sim twin`)."""
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
                cmd = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == edge_pid and b"twin" in cmd:
                return int(entry.name)
    raise SystemExit("the edge's lab process was not found")


@dataclass
class Boards:
    """A lab of several cameras, one board per camera and a fuser on one broker."""

    lab: LabClient
    lab_pid: int
    boards: dict[str, int]  # camera -> its edge's pid
    fuser_pid: int
    http_port: int  # the first board's dashboard
    observer: Observer
    ids: list[str]


@contextmanager
def boards(workdir: Path, cameras: int, rovers: int) -> Iterator[Boards]:
    state = workdir / "s"
    env = _env(state, EDGE_IPS_DASHBOARD__TOKEN=TOKEN)
    procs: list[subprocess.Popen[bytes]] = []

    def spawn(name: str, args: list[str], **extra: str) -> subprocess.Popen[bytes]:
        with (workdir / f"{name}.log").open("wb") as out:
            proc = subprocess.Popen([*EDGE_IPS, *args], env={**env, **extra}, stdout=out, stderr=out, cwd=workdir)
        procs.append(proc)
        return proc

    with private_mosquitto(workdir / "mosquitto", MOSQUITTO_BENCH) as broker:
        try:
            lab_proc = spawn(
                "lab", ["sim", "twin", "--cameras", str(cameras), "--rovers", str(rovers), "--broker", broker.url]
            )
            lab = LabClient(state / "twin.sock")
            _wait("the lab", lambda: _answers(lab))
            names = [c["name"] for c in lab.status()["cameras"]]
            ports = {name: free_port() for name in names}
            board_args = ["start", "--broker", broker.url, "--edge-id"]
            edges = {
                name: spawn(
                    name,
                    [*board_args, name, "--source", f"sim:twin:{name}", "--http-port", str(ports[name])],
                    EDGE_IPS_EDGE__PUBLISH="detections",
                )
                for name in names
            }
            fuser = spawn("fuser", ["fuse", "--broker", broker.url, "--id", "fuser-a", "--max-age", "1.0"])
            for name in names:
                _wait(f"board {name} online", lambda name=name: _healthy(ports[name]))
            ids = [r["id"] for r in lab.status()["rovers"]]
            observer = Observer(broker.port)
            try:
                yield Boards(
                    lab, lab_proc.pid, {n: p.pid for n, p in edges.items()}, fuser.pid, ports[names[0]], observer, ids
                )
            finally:
                observer.close()
        finally:
            for proc in reversed(procs):
                proc.send_signal(signal.SIGTERM)
                proc.wait(60)


def cpu_cameras(cameras: int, rovers: int, seconds: float) -> dict[str, Any]:
    """The lab of ``cameras`` cameras with a board each and a fuser, the rovers driving a rendezvous (scattered every
    8 s): CPU % of a core of each part over ``seconds``, each camera's frame rate, the fused poses' latency."""
    with tempfile.TemporaryDirectory(prefix=f"twin-cams{cameras}-") as tmp, boards(Path(tmp), cameras, rovers) as b:
        t = Fleet(b.lab, b.http_port, b.observer, b.ids)
        t.command("rendezvous")
        t.scatter_and_track()
        pids = {"lab": b.lab_pid, **{f"board {n}": p for n, p in b.boards.items()}, "fuser": b.fuser_pid}
        c0, before, w0 = {k: _cpu_s(p) for k, p in pids.items()}, t.lab.status(), time.monotonic()
        last_scatter = w0
        while time.monotonic() - w0 < seconds:
            time.sleep(0.5)
            if time.monotonic() - last_scatter > 8.0:
                t.lab.scatter()
                last_scatter = time.monotonic()
        wall = time.monotonic() - w0
        after = t.lab.status()
        processes = {k: round(100 * (_cpu_s(p) - c0[k]) / wall, 1) for k, p in pids.items()}
        cams = []
        for c1, c0_ in zip(after["cameras"], before["cameras"], strict=True):
            name = c1["name"]
            render = after["cpu_s"]["cameras"][name] - before["cpu_s"]["cameras"][name]
            cams.append(
                {
                    "camera": name,
                    "render_cpu_pct": round(100 * render / wall, 1),
                    "fps": round((c1["frames"] - c0_["frames"]) / wall, 1),
                    "skipped": c1["skipped"] - c0_["skipped"],
                    "board_cpu_pct": processes[f"board {name}"],
                }
            )
        return {
            "cameras": cameras,
            "rovers": rovers,
            "seconds": round(wall, 1),
            "cpu_pct": processes,
            "total_cpu_pct": round(sum(processes.values()), 1),
            "per_camera": cams,
            "lab_parts_pct": _parts_pct(before["cpu_s"], after["cpu_s"], wall),
            "fused_pose_latency_ms": _latency(t.observer.since(time.time() - wall)),
            "load_average": os.getloadavg(),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("run", help="one recorded run of the three formations")
    r.add_argument("--out", type=Path, default=Path("runs/twin"))
    r.add_argument("--repeat", type=int, default=1, help="the three formations this many times")
    c = sub.add_parser("cpu", help="CPU of the lab and the edge by fleet size")
    c.add_argument("--rovers", default="3,6,9,12")
    c.add_argument("--seconds", type=float, default=30.0)
    c.add_argument("--cameras", type=int, default=1, help="2-4: boards over the wide arena, a fuser (one --rovers)")
    args = parser.parse_args()
    if args.what == "run":
        print(json.dumps(run(args.out, args.repeat), indent=2))
    elif args.cameras > 1:
        print(json.dumps(cpu_cameras(args.cameras, int(args.rovers.split(",")[0]), args.seconds), indent=2))
    else:
        print(json.dumps(cpu([int(x) for x in args.rovers.split(",")], args.seconds), indent=2))


if __name__ == "__main__":
    main()
