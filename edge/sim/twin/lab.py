"""The twin's lab: a floor with rovers on it, a camera above it, and each rover's firmware, all in real time.

::

    firmware (one thread per rover)  --PWM duties-->  world (rigid bodies, the drive model of `sim formation`)
          ^                                                   |
          | poses, formation (MQTT, through the real broker)  | rendered every 1/30 s (the paper's lab)
          |                                                   v
    edge-ips start  <--------- camera frames (the lab's socket, as a webcam) ---------  camera

With ``cameras`` > 1 the floor is the wide arena (:mod:`edge.sim.twin.views`): each camera renders the one world
on its own thread into its own readers' slots, and each board (an ``edge-ips start --source sim:twin:camK``) reads
its own camera.

The world is the one the closed-loop experiments use: :class:`~edge.sim.world.World`'s differential drive with the
rover's config-derived wheel speeds, dead band and acceleration limit, and the motor physics of
:class:`~edge.sim.rover.MotorPhysics` (gain error, noise, actuation delay), with bodies that cannot pass through
each other (:class:`~edge.sim.contact.SolidWorld`). A physics thread moves it every :data:`PHYSICS_PERIOD_S` by
the wheel speeds each rover's motor duties stand for at that moment, as wheels follow an H-bridge.

Faults the lab can cause: a rover's Wi-Fi gone for a while (its station loses the access point), a camera hanging
(no pictures, the stream open; with several cameras, that one only). For every fault, the lab's own or one the
edge announces (:meth:`TwinLab.note`: a broker restart, the edge killed), it times how long each rover takes to
come to rest, from the ground truth.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge.camera import PinholeCamera
from edge.errors import ConfigError
from edge.sim.contact import SolidWorld
from edge.sim.link import LinkSettings
from edge.sim.rover import BODY_LENGTH_CM, BODY_WIDTH_CM, MotorPhysics, fleet_drive_model, rover_looks
from edge.sim.scene import Heading
from edge.sim.starts import random_layout
from edge.sim.twin.camera import TwinCamera
from edge.sim.twin.rovers import TwinRover, thread_cpu_s
from edge.sim.twin.views import CAMERA_COUNTS, LabView, lab_floor
from edge.sim.twin.wire import LAB_FAULTS, CameraDescription
from edge.sim.world import Pose, WheelCommand, WorldState
from edge.tracker_config import RoverConfig

PHYSICS_PERIOD_S = 0.01
REST_CM_S = 0.01  # a wheel slower than this is at rest (the world's speeds reach exactly 0 when the motors stop)
MAX_FAULT_S = 300.0
MAX_ROVERS = 12


@dataclass(frozen=True)
class LabSettings:
    """``rovers`` 1-12; ``seed``: starting layout, scatters, motors, links, camera noise; ``heading``: two-tone
    markers (heading even standing still) or one colour; ``camera_latency_ms``: exposure to hand-over (a USB
    webcam's readout, transfer and decoding); ``physics``: how far the motors are from the firmware's duty model;
    ``link``: each rover's Wi-Fi (:class:`~edge.sim.link.LinkSettings`, ``--link``; the default delays nothing);
    ``cameras``: 1 (the paper's lab) or 2-4 boards over the wide arena (:mod:`edge.sim.twin.views`)."""

    rovers: int = 3
    seed: int = 0
    heading: Heading = "two_tone"
    fps: float = 30.0
    camera_latency_ms: float = 40.0
    physics: MotorPhysics = field(default_factory=MotorPhysics)
    link: LinkSettings = field(default_factory=LinkSettings)
    cameras: int = 1

    def __post_init__(self) -> None:
        if self.cameras not in CAMERA_COUNTS:
            raise ConfigError(f"--cameras must be one of {', '.join(map(str, CAMERA_COUNTS))}, got {self.cameras}")
        if not 1 <= self.rovers <= MAX_ROVERS:
            raise ConfigError(f"--rovers must be 1-{MAX_ROVERS}, got {self.rovers}")
        if not 0.0 <= self.camera_latency_ms <= 1000.0:
            raise ConfigError(f"--camera-latency-ms must be 0-1000, got {self.camera_latency_ms:g}")


class LabEvents:
    """What happened in the lab, newest last: shown to its operator (``echo``) and to the dashboard."""

    def __init__(self, echo: Callable[[str], None] | None = None, keep: int = 200) -> None:
        self.echo = echo
        self._lines: deque[dict[str, Any]] = deque(maxlen=keep)
        self._lock = threading.Lock()
        self.count = 0

    def add(self, who: str, text: str, **data: Any) -> None:
        """One event; ``data``: what a program reads from it (a rest timing: ``rest={...}``)."""
        with self._lock:
            self.count += 1
            self._lines.append({"n": self.count, "t": round(time.time(), 3), "who": who, "text": text, **data})
        if self.echo is not None:
            self.echo(f"{time.strftime('%H:%M:%S')} {who}: {text}")

    def recent(self, after: int = 0) -> list[dict[str, Any]]:
        with self._lock:
            return [e for e in self._lines if e["n"] > after]


@dataclass
class _Fault:
    kind: str
    rover: str | None
    until: float
    label: str


@dataclass
class _RestWatch:
    """Rovers to time from ``started`` until they are at rest (``label``: the cause)."""

    label: str
    started: float
    waiting: set[str]


class TwinLab:
    """The world, the cameras and the rovers (see the module docstring). ``configs``: each rover's checked firmware
    config, its broker address and login included. :meth:`start` runs the world and the camera; :meth:`start_rovers`
    switches the rovers on (once their broker is there)."""

    def __init__(
        self,
        settings: LabSettings,
        configs: Sequence[Mapping[str, Any]],
        *,
        events: LabEvents | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if len(configs) != settings.rovers:
            raise ConfigError(f"twin lab: {settings.rovers} rovers asked for, {len(configs)} configs given")
        self.settings = settings
        self.events = events or LabEvents()
        self.clock = clock
        self.configs = [dict(c) for c in configs]
        self.ids = tuple(str(c["id"]) for c in configs)
        self._rng = np.random.default_rng(np.random.SeedSequence([settings.seed, 0x7419]))
        self.floor = lab_floor(
            settings.cameras, rover_looks(self.configs, settings.heading), settings.seed, settings.fps
        )
        self.world = SolidWorld(
            dict(zip(self.ids, self._layout(), strict=True)),
            fleet_drive_model(self.configs, settings.physics),
            bodies_cm=(BODY_LENGTH_CM, BODY_WIDTH_CM),
            seed=settings.seed,
        )
        self._world_lock = threading.Lock()
        self.cameras = {
            view.name: TwinCamera(
                view.render,
                self.state,
                fps=settings.fps,
                latency_s=settings.camera_latency_ms / 1000.0,
                clock=clock,
                name=view.name,
            )
            for view in self.floor.views
        }
        self.rovers: list[TwinRover] = []
        self._faults: list[_Fault] = []
        self._watches: list[_RestWatch] = []
        self._lock = threading.Lock()  # faults and watches
        self._stop = threading.Event()
        self._physics: threading.Thread | None = None
        self._stepped = threading.Condition()  # notified after every physics step (what a waiting client checks)

    # -- what the camera sees and what the edge is told -------------------------------------------------------------
    def state(self) -> WorldState:
        with self._world_lock:
            return self.world.state()

    @property
    def camera(self) -> TwinCamera:
        """The first camera (the only one of the paper's lab)."""
        return self.cameras[self.floor.views[0].name]

    @property
    def camera_model(self) -> PinholeCamera:
        return self.floor.views[0].camera

    @property
    def rover_configs(self) -> tuple[RoverConfig, ...]:
        """The rovers as the first camera sees them."""
        return self.floor.views[0].rover_configs

    def camera_named(self, name: str | None) -> tuple[LabView, TwinCamera]:
        """The camera ``name`` (the first when None); :class:`ConfigError` naming the lab's cameras otherwise."""
        view = self.floor.view(name)
        return view, self.cameras[view.name]

    def describe(self, name: str | None = None) -> CameraDescription:
        """What a reader of camera ``name`` (the first when None) is told: its model, its view of the rovers."""
        s = self.settings
        view, _ = self.camera_named(name)
        which = "" if len(self.cameras) == 1 else f"{view.name} of {len(self.cameras)} over the wide arena, "
        return CameraDescription(
            view.camera.width_px,
            view.camera.height_px,
            s.fps,
            view.camera,
            view.rover_configs,
            f"twin lab: {which}{len(self.ids)} rovers ({', '.join(self.ids)}), seed {s.seed}, "
            f"camera latency {s.camera_latency_ms:g} ms, link {'wire' if s.link.is_wire else s.link}",
            name=view.name,
            region_cm=view.region_cm,
        )

    # -- life cycle ---------------------------------------------------------------------------------------------------
    def start(self) -> TwinLab:
        self._physics = threading.Thread(target=self._run_physics, name="twin-physics", daemon=True)
        self._physics.start()
        for camera in self.cameras.values():
            camera.start(self._stop)
        return self

    def start_rovers(self, configs: Sequence[Mapping[str, Any]] | None = None) -> None:
        """Each rover's firmware on its own thread, connecting to its broker with its own login (``configs``: the
        rovers' configs with their logins, in the lab's order; default: those the lab was built with)."""
        configs = self.configs if configs is None else [dict(c) for c in configs]
        if [str(c["id"]) for c in configs] != list(self.ids):
            raise ConfigError(f"twin lab: configs for {[c['id'] for c in configs]}, not for {list(self.ids)}")
        link, seed = self.settings.link, self.settings.seed
        rovers = [
            TwinRover(cfg, link=link, seed=(seed, k), on_event=self.events.add, clock=self.clock)
            for k, cfg in enumerate(configs)
        ]
        for rover in rovers:
            rover.start(self._stop)
        self.rovers = rovers
        self.events.add("lab", f"rovers switched on: {', '.join(self.ids)}")

    def close(self) -> None:
        """Stop everything; each rover says goodbye (offline status, clean disconnect)."""
        self._stop.set()
        for rover in self.rovers:
            rover.close()
        if self._physics is not None:
            self._physics.join(5.0)
        for camera in self.cameras.values():
            camera.join()

    @property
    def stopped(self) -> threading.Event:
        return self._stop

    # -- physics ------------------------------------------------------------------------------------------------------
    def _run_physics(self) -> None:
        last = self.clock()
        while not self._stop.wait(PHYSICS_PERIOD_S):
            now = self.clock()
            dt = min(now - last, 0.25)  # a process starved for longer than that resumes rather than jumps
            last = now
            commands = {r.id: WheelCommand(*r.wheels_cm_s) for r in self.rovers}
            with self._world_lock:
                state = self.world.step(dt, commands)
            self._after_step(state, now)
            with self._stepped:
                self._stepped.notify_all()

    def wait_until(self, ready: Callable[[], bool], timeout_s: float) -> bool:
        """Whether ``ready()`` came true within ``timeout_s``, checked after every physics step (a fault's or a
        note's event shows by the next one): how a control client waits for the lab without polling it."""
        with self._stepped:
            return self._stepped.wait_for(ready, timeout_s)

    def fastest_cm_s(self) -> float:
        """The speed of the fastest rover by the ground truth."""
        return max((math.hypot(r.vx_cm_s, r.vy_cm_s) for r in self.state().rovers), default=0.0)

    def _at_rest(self, state: WorldState) -> set[str]:
        track_cm = self.world.drive.track_width_cm
        rest = REST_CM_S
        return {r.rover_id for r in state.rovers if abs(r.v_cm_s) < rest and abs(r.omega_rad_s) * track_cm < rest}

    def _after_step(self, state: WorldState, now: float) -> None:
        at_rest = self._at_rest(state)
        fresh = {r.id: r.last_fresh_s for r in self.rovers}
        with self._lock:
            for watch in self._watches:
                for rover_id in sorted(watch.waiting & at_rest):
                    pose = fresh.get(rover_id)
                    rest = {"fault": watch.label, "after_fault_s": round(now - watch.started, 3)}
                    since = ""
                    if pose is not None:
                        rest["after_pose_s"] = round(now - pose, 3)
                        since = f"{now - pose:.2f} s after its last fresh pose, "
                    text = f"at rest {since}{now - watch.started:.2f} s after {watch.label}"
                    self.events.add(rover_id, text, rest=rest)
                watch.waiting -= at_rest
            self._watches = [w for w in self._watches if w.waiting and now - w.started < MAX_FAULT_S]
            over = [f for f in self._faults if f.until <= now]
            self._faults = [f for f in self._faults if f.until > now]
        for fault in over:
            self.events.add(fault.rover or "lab", f"fault over: {fault.label}")

    def _watch(self, label: str, rovers: Sequence[str]) -> None:
        """Time how long each of ``rovers`` that is moving now takes to come to rest."""
        still = self._at_rest(self.state())
        for rover_id in rovers:
            if rover_id in still:
                self.events.add(rover_id, f"was at rest already when {label}", rest={"fault": label, "already": True})
        with self._lock:
            self._watches.append(_RestWatch(label, self.clock(), set(rovers) - still))

    # -- what an operator (or the dashboard) can do -------------------------------------------------------------------
    def _layout(self) -> list[Pose]:
        n = len(self.ids)
        return list(random_layout(n, self._rng, 150.0 if n <= 8 else 100.0, 40.0, area_cm=self.floor.area_cm))

    def scatter(self) -> dict[str, tuple[float, float]]:
        """Every rover picked up and put down at a random free spot of the floor (the closed-loop experiments'
        starts: at least 150 cm apart, 100 cm for more than 8 rovers, 40 cm from the edges), facing anywhere."""
        placed = dict(zip(self.ids, self._layout(), strict=True))
        with self._world_lock:
            for rover_id, pose in placed.items():
                self.world.place(rover_id, pose)
        where = {rid: (round(p.x_cm, 1), round(p.y_cm, 1)) for rid, p in placed.items()}
        self.events.add("lab", "scattered: " + ", ".join(f"{rid} at ({x:g}, {y:g})" for rid, (x, y) in where.items()))
        return where

    def fault(self, kind: str, seconds: float, rover: str | None = None, camera: str | None = None) -> str:
        """Cause a lab fault (``wifi`` of one rover, or ``camera``: the camera ``camera`` hangs, the first when
        None) for ``seconds``; returns what was done. The rovers timed to rest: the Wi-Fi's one, or those only the
        hung camera sees (with one camera, all)."""
        if kind not in LAB_FAULTS:
            raise ConfigError(f"the lab causes {' and '.join(LAB_FAULTS)} faults, not {kind!r}")
        if not 0.0 < seconds <= MAX_FAULT_S:
            raise ConfigError(f"a fault lasts more than 0 and at most {MAX_FAULT_S:g} s, not {seconds:g}")
        if kind == "wifi":
            target = next((r for r in self.rovers if r.id == rover), None)
            if target is None:
                known = ", ".join(self.ids)
                raise ConfigError(f"no rover {rover!r} in the lab (rovers: {known})" if rover else "which rover?")
            outage = target.drop_wifi(seconds)
            lost = ", the association with it" if outage.dropped else ""
            label = f"{target.id}'s Wi-Fi gone for {seconds:g} s{lost}"
            watched: Sequence[str] = [target.id]
        else:
            view, hung = self.camera_named(camera)
            label = (
                f"camera hung for {seconds:g} s" if len(self.cameras) == 1 else f"{view.name} hung for {seconds:g} s"
            )
            hung.stall(seconds)
            watched = self._seen_only_by(view)
        with self._lock:
            self._faults.append(_Fault(kind, rover, self.clock() + seconds, label))
        self.events.add(rover if kind == "wifi" and rover else "lab", f"fault: {label}")
        self._watch(label, watched)
        return label

    def _seen_only_by(self, view: LabView) -> list[str]:
        others = [v for v in self.floor.views if v is not view]
        where = self.state().by_id()
        return [r for r in self.ids if not any(v.sees(where[r].x_cm, where[r].y_cm) for v in others)]

    def note(self, label: str) -> None:
        """An edge-side fault is about to happen (``label``): time how fast every rover comes to rest."""
        self.events.add("edge", f"fault: {label}")
        self._watch(label, self.ids)

    def cpu_s(self) -> dict[str, Any]:
        """CPU seconds used so far by the cameras (rendering: all of them, and each), the physics, and each rover (its
        firmware's thread and its link's relay)."""
        cameras = {name: round(thread_cpu_s(c.thread), 3) for name, c in self.cameras.items()}
        return {
            "camera": round(sum(cameras.values()), 3),
            "cameras": cameras,
            "physics": round(thread_cpu_s(self._physics), 3),
            "rovers": {r.id: {"firmware": round(r.cpu_s()[0], 3), "link": round(r.cpu_s()[1], 3)} for r in self.rovers},
        }

    def status(self, events_after: int = 0, camera: str | None = None) -> dict[str, Any]:
        """Rovers (with their ground truth), faults, events, CPU, and the cameras: ``cameras`` lists every one,
        ``camera`` is the one named (the first when None: a single camera's client)."""
        now = self.clock()
        state = self.state().by_id()
        with self._lock:
            faults = [
                {"kind": f.kind, "rover": f.rover, "label": f.label, "left_s": round(f.until - now, 1)}
                for f in self._faults
            ]
        still = self._at_rest(self.state())
        on = {r.id: r for r in self.rovers}
        rovers = [
            {
                "id": rid,
                "switched_on": rid in on,
                "connected": rid in on and on[rid].connected,
                "moving": rid not in still,
                "speed_cm_s": round(math.hypot(state[rid].vx_cm_s, state[rid].vy_cm_s), 1),
                "truth": {
                    "x": round(state[rid].x_cm, 2),
                    "y": round(state[rid].y_cm, 2),
                    "theta": round(state[rid].theta_rad, 4),
                },
                "pose_delay_ms": _delay_figures(on[rid].pose_delays_s()) if rid in on else None,
            }
            for rid in self.ids
        ]
        return {
            "t": round(time.time(), 3),
            "cpu_s": self.cpu_s(),
            "link": "wire" if self.settings.link.is_wire else str(self.settings.link),
            "rovers": rovers,
            "faults": faults,
            "events": self.events.recent(events_after),
            "area_cm": list(self.floor.area_cm),
            "camera": _camera_status(*self.camera_named(camera)),
            "cameras": [_camera_status(view, self.cameras[view.name]) for view in self.floor.views],
        }


def _camera_status(view: LabView, camera: TwinCamera) -> dict[str, Any]:
    return {
        "name": view.name,
        "region_cm": [round(v, 1) for v in view.region_cm],
        "frames": camera.frames,
        "skipped": camera.skipped,
        "readers": camera.readers,
        "stalled": camera.stalled,
    }


def _delay_figures(delays_s: Sequence[float]) -> dict[str, float] | None:
    """Median, 95th and 99th percentile of a rover's pose air delays, ms (None before any pose)."""
    if not delays_s:
        return None
    p50, p95, p99 = np.percentile(np.asarray(delays_s) * 1000.0, [50, 95, 99])
    return {"p50": round(float(p50), 1), "p95": round(float(p95), 1), "p99": round(float(p99), 1)}
