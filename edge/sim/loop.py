"""The closed loop: simulated rovers, a rendered camera, the edge's tracker, MQTT over Wi-Fi, the rovers' firmware.

::

    World (differential drive: wheel limits, gain error, noise, delay)
      -> CameraPath: Renderer (the paper's lab as the webcam sees it) -> the tracker `edge-ips start` runs
                                                                                    every 1/30 s of simulated time
      -> the pose publishing rule of the runtime (edge.poses) -> MqttPublisher -> a real broker
      -> Fleet: per rover a LinkRelay carrying its MQTT connection over its Wi-Fi LinkModel (edge.sim.link)
         -> edge.rover_host.HostRover (the firmware's real modules; host stand-ins for machine/network)
      -> PWM duties -> wheel speeds (the duty model inverted) -> World                   every 20 ms (the firmware)

Time: the world, the camera, the links and the firmware run on one simulated clock (:class:`SimClock`, integer
microseconds). A frame captured at ``t`` is published ``latency_ms`` later (readout, USB, tracking); the poses cross
the broker in real time, and the loop waits at most ``deliver_timeout_s`` of real time for the broker to hand them to
every rover's link (a pose that misses the window is *late*: its link gets it, and stamps it, later). Each link
then delivers what it carries when its model says, in order, at the rover's control steps; the firmware reads what
has arrived, 16 messages a step at most, as on the chip. Nothing is bypassed: a frame the tracker misreads, a pose
the publisher drops while disconnected, a Wi-Fi outage, all reach the rovers' behaviour.

Scripted runs (``edge-ips sim trajectory``) follow :mod:`edge.sim.trajectories` plans instead of the firmware; the
poses still go through the tracker, the publisher and the broker.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera, paper_camera
from edge.errors import ConfigError, SimulationError
from edge.messages import FORMATION_TOPIC, dumps, pose_topic
from edge.poses import PoseSink, publish_poses
from edge.sim.camera_path import CameraPath, annotate, build_tracker, marker_colors
from edge.sim.link import LinkSettings, Outage
from edge.sim.loop_fleet import Fleet, LoopBroker, MotorLog
from edge.sim.metrics import FORMATIONS, Bar
from edge.sim.relay import RelayLog
from edge.sim.rover import (
    MotorPhysics,
    fleet_drive_model,
    fleet_ids,
    rover_config,
    rover_looks,
)
from edge.sim.scene import Heading
from edge.sim.starts import random_layout, trajectory_plans
from edge.sim.world import Plan, WheelCommand, World
from edge.tracking import RoverEstimate

__all__ = ["FPS", "ClosedLoop", "LoopConfig", "LoopParts", "LoopRecord", "MotorLog", "SimClock", "marker_colors", "run"]

TRAJECTORIES = ("circle", "diagonal")
FPS = 30.0
US = 1_000_000
SNAPSHOT_EVERY = 15  # frames kept (downscaled) for the snapshot figure


@dataclass(frozen=True)
class LoopConfig:
    """One closed-loop run.

    ``kind``: a formation (line, rendezvous, triangle) or a trajectory (circle, diagonal). ``broker_url``: None
    for the embedded broker, else ``mqtt://host:port``. ``link``: the Wi-Fi between the broker and each rover (the
    default passes everything at the rover's next step). ``feed_stop_frame``: the camera feed stops at this frame
    (nothing more is tracked or published). ``broker_stop_frame``: the broker is killed at this frame.
    """

    kind: str
    rovers: int = 3
    seed: int = 0
    frames: int | None = None
    broker_url: str | None = None
    heading: Heading = "two_tone"
    latency_ms: float = 50.0
    deliver_timeout_s: float = 0.25
    link: LinkSettings = field(default_factory=LinkSettings)
    feed_stop_frame: int | None = None
    broker_stop_frame: int | None = None
    physics: MotorPhysics = field(default_factory=MotorPhysics)
    min_start_gap_cm: float | None = None  # None: 150 cm, 100 cm for more than 8 rovers (no more fit 150 apart)
    start_margin_cm: float = 40.0

    def __post_init__(self) -> None:
        if self.kind not in FORMATIONS + TRAJECTORIES:
            raise ConfigError(f"unknown experiment {self.kind!r}: use one of {', '.join(FORMATIONS + TRAJECTORIES)}")
        if not 1 <= self.rovers <= 12:
            raise ConfigError(f"--rovers must be 1-12, got {self.rovers}")
        if self.kind == "triangle" and self.rovers < 3:
            raise ConfigError("a triangle needs at least 3 rovers")
        if self.kind in FORMATIONS and self.rovers < 2:
            raise ConfigError(f"a {self.kind} formation needs at least 2 rovers")
        if self.frames is not None and self.frames < 1:
            raise ConfigError(f"--frames must be at least 1, got {self.frames}")
        if self.latency_ms < 0 or self.deliver_timeout_s <= 0:
            raise ConfigError("latency must not be negative and the delivery window must be positive")
        if self.broker_url is not None:
            from edge.config import parse_broker_url

            try:
                parse_broker_url(self.broker_url)  # a bad URL is said before anything is run or written
            except ValueError as exc:
                raise ConfigError(f"--broker: {exc}") from None

    @property
    def formation(self) -> bool:
        return self.kind in FORMATIONS

    @property
    def bar(self) -> Bar:
        return Bar(self.kind)

    @property
    def n_frames(self) -> int:
        return self.frames if self.frames is not None else 360


@dataclass
class LoopRecord:
    """Everything a run produced, in memory: enough to recompute every metric and draw every figure."""

    config: LoopConfig
    ids: tuple[str, ...]
    camera: PinholeCamera
    fps: float
    truth: NDArray[np.float64]  # (F, N, 3) x, y, theta of the marker centre at each frame's capture time
    measured: NDArray[np.float64]  # (F, N, 3) what the tracker gave (NaN: not seen; theta NaN: no heading)
    published: list[tuple[int, str, bytes]]  # (frame, rover id, payload) in publishing order
    motors: dict[str, MotorLog]
    fresh_ms: dict[str, list[int]]  # simulated times at which each rover received a new pose of its own
    deliveries_late: dict[str, int]  # rover -> frames whose poses the broker had not handed its link in the window
    poses_dropped: int  # not handed to the broker (publisher disconnected)
    snapshots: dict[int, NDArray[np.uint8]]  # frame -> downscaled camera image
    overlays: dict[int, list[tuple[str, float, float]]]  # frame -> (id, u, v) of the tracker's estimates, full-res px
    formation: dict[str, Any] | None = None
    plans: dict[str, Plan] | None = None
    outages: dict[str, list[Outage]] = field(default_factory=dict)  # rover -> its link's outages during the run
    links: dict[str, RelayLog] = field(default_factory=dict)  # rover -> what crossed its link
    wall_s: float = 0.0
    frames_tracked: int = 0


@dataclass
class SimClock:
    """The loop's one clock: simulated time in integer microseconds."""

    now_us: int = 0

    @property
    def now_s(self) -> float:
        return self.now_us / US

    @property
    def now_ms(self) -> int:
        return self.now_us // 1000

    def monotonic(self) -> float:
        return self.now_s


@dataclass(frozen=True)
class LoopHooks:
    """Callbacks of a run: ``on_frame(k)`` before frame ``k`` is captured (a test kills a broker there),
    ``progress(k)`` after it, ``video(image)`` with every tracked frame annotated with the tracker's estimates."""

    on_frame: Callable[[int], None] | None = None
    progress: Callable[[int], None] | None = None
    video: Callable[[NDArray[np.uint8]], None] | None = None


@dataclass(frozen=True)
class LoopParts:
    """The collaborators of one run."""

    world: World
    camera: CameraPath
    publisher: PoseSink
    fleet: Fleet | None  # None: scripted rovers, no firmware
    broker: LoopBroker
    clock: SimClock


@dataclass(frozen=True)
class _Tracked:
    """A frame's estimates waiting to be published at ``due_us``."""

    due_us: int
    frame: int
    t_capture_s: float
    estimates: tuple[RoverEstimate, ...]


class ClosedLoop:
    """One run's event loop over its :class:`LoopParts`. :meth:`run` advances the clock from event to event (a
    frame, a frame's poses due at the publisher, a control step); :meth:`record` is what it recorded."""

    def __init__(self, config: LoopConfig, parts: LoopParts, hooks: LoopHooks, n_frames: int) -> None:
        self.config = config
        self.world = parts.world
        self.camera = parts.camera
        self.publisher = parts.publisher
        self.fleet = parts.fleet
        self.broker = parts.broker
        self.clock = parts.clock
        self.hooks = hooks
        self.n_frames = n_frames
        self.ids = self.world.rover_ids
        self._index = {rid: k for k, rid in enumerate(self.ids)}
        self._seq = {rid: 0 for rid in self.ids}
        self._pending: deque[_Tracked] = deque()
        self._commands: dict[str, WheelCommand] = {}
        fleet = self.fleet
        self._period_us = fleet.period_ms * 1000 if fleet is not None and fleet.rovers else None
        self._latency_us = round(config.latency_ms * 1000)
        self.truth = np.full((n_frames, len(self.ids), 3), np.nan)
        self.measured = np.full((n_frames, len(self.ids), 3), np.nan)
        self.published: list[tuple[int, str, bytes]] = []
        self.snapshots: dict[int, NDArray[np.uint8]] = {}
        self.overlays: dict[int, list[tuple[str, float, float]]] = {}
        self.frames_tracked = 0

    def run(self) -> None:
        frame_k = 0
        step_j = 1  # the firmware stepped once at t = 0 when it got the formation
        while frame_k < self.n_frames or self._pending:
            t_frame = round(frame_k * US / FPS) if frame_k < self.n_frames else math.inf
            t_step = step_j * self._period_us if self._period_us is not None else math.inf
            t_deliver = self._pending[0].due_us if self._pending else math.inf
            t_next = min(t_frame, t_step, t_deliver)
            self._advance(int(t_next))
            if t_deliver == t_next:
                self._publish(self._pending.popleft())
            elif t_frame == t_next:
                self._capture(frame_k)
                frame_k += 1
            else:
                assert self.fleet is not None
                self._commands = self.fleet.step(self.clock.now_ms)
                step_j += 1

    def _advance(self, t_us: int) -> None:
        if t_us > self.clock.now_us:
            self.world.step((t_us - self.clock.now_us) / US, self._commands)
            self._commands = {}
            self.clock.now_us = t_us

    def _capture(self, k: int) -> None:
        if self.hooks.on_frame is not None:
            self.hooks.on_frame(k)
        if self.config.broker_stop_frame is not None and k == self.config.broker_stop_frame:
            self.broker.kill()
        state = self.world.state()
        for r in state.rovers:
            self.truth[k, self._index[r.rover_id]] = (r.x_cm, r.y_cm, r.theta_rad)
        if self.config.feed_stop_frame is None or k < self.config.feed_stop_frame:
            seen = self.camera.capture(state, k, self.clock.now_s)
            self.frames_tracked += 1
            for est in seen.estimates:
                theta = est.theta_rad if est.theta_rad is not None else math.nan
                self.measured[k, self._index[est.rover_id]] = (est.x_cm, est.y_cm, theta)
            t_capture = self.camera.wall0_s + self.clock.now_s
            self._pending.append(_Tracked(self.clock.now_us + self._latency_us, k, t_capture, seen.estimates))
            marks = [(m.rover_id, m.u_px, m.v_px) for m in seen.marks]
            if k % SNAPSHOT_EVERY == 0 or k == self.n_frames - 1:
                self.snapshots[k] = seen.image[::2, ::2].copy()
                self.overlays[k] = marks
            if self.hooks.video is not None:
                self.hooks.video(annotate(seen.image, seen.marks))
        if self.hooks.progress is not None:
            self.hooks.progress(k)

    def _publish(self, tracked: _Tracked) -> None:
        out = publish_poses(self.publisher, tracked.estimates, self._seq, tracked.frame, tracked.t_capture_s)
        self.published.extend((tracked.frame, rid, payload) for rid, payload in out.sent)
        if out.sent and self.fleet is not None:
            newest = {pose_topic(rid): payload for rid, payload in out.sent}
            self.fleet.await_poses(newest, self.config.deliver_timeout_s)

    def record(self, poses_dropped: int) -> LoopRecord:
        fleet = self.fleet
        end_s = self.clock.now_s
        return LoopRecord(
            config=self.config,
            ids=self.ids,
            camera=self.camera.camera,
            fps=FPS,
            truth=self.truth,
            measured=self.measured,
            published=self.published,
            motors=dict(fleet.motors) if fleet is not None else {},
            fresh_ms=dict(fleet.fresh_ms) if fleet is not None else {},
            deliveries_late=dict(fleet.late) if fleet is not None else {},
            poses_dropped=poses_dropped,
            snapshots=self.snapshots,
            overlays=self.overlays,
            outages={rid: m.outages(end_s) for rid, m in fleet.models.items()} if fleet is not None else {},
            links=fleet.link_logs() if fleet is not None else {},
            frames_tracked=self.frames_tracked,
        )


def formation_message(kind: str, ids: tuple[str, ...], bar: Bar, seq: int = 1) -> Any:
    """The retained formation the edge publishes: the paper's vertical line (``theta`` null: either end), a
    rendezvous, a triangle of ``side_cm``; free to settle anywhere (no ``x``/``y`` anchor)."""
    from edge.commands import build_formation

    if kind == "line":
        return build_formation("line", ids, seq=seq, spacing_cm=bar.spacing_cm)
    if kind == "triangle":
        return build_formation("triangle", ids, seq=seq, side_cm=bar.side_cm)
    return build_formation("rendezvous", ids, seq=seq)


def run(
    config: LoopConfig,
    *,
    on_frame: Callable[[int], None] | None = None,
    progress: Callable[[int], None] | None = None,
    video: Callable[[NDArray[np.uint8]], None] | None = None,
) -> LoopRecord:
    """Run one experiment end to end and return what it recorded (the callbacks: :class:`LoopHooks`)."""
    from edge.publisher import MqttPublisher
    from edge.sim.render import Renderer
    from edge.sim.scene import Scene
    from edge.sim.setup import lab_effects, scenario_rng

    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x100B]))
    ids = fleet_ids(config.rovers)
    configs = [rover_config(rid) for rid in ids]
    camera = paper_camera()
    scene = Scene(rover_looks(configs, config.heading))
    effects = lab_effects(scenario_rng("lab", config.seed))
    plans: dict[str, Plan] | None = None
    n_frames = config.n_frames
    drive = fleet_drive_model(configs, config.physics)
    if config.formation:
        gap = config.min_start_gap_cm
        if gap is None:
            gap = 150.0 if config.rovers <= 8 else 100.0
        starts = random_layout(config.rovers, rng, gap, config.start_margin_cm)
        world = World(dict(zip(ids, starts, strict=True)), drive, seed=config.seed)
    else:
        plans = dict(zip(ids, trajectory_plans(config.kind, config.rovers, rng), strict=True))
        world = World(dict(plans), drive, seed=config.seed)
        if config.frames is None:
            n_frames = math.ceil(max(p.duration_s for p in plans.values()) * FPS) + 1
    camera_path = CameraPath(
        Renderer(camera, scene, effects, seed=config.seed, fps=FPS),
        build_tracker(camera, scene, effects, config.seed, FPS),
        ids,
        wall0_s=time.time(),
    )
    clock = SimClock()
    broker = LoopBroker(config.broker_url)
    publisher = MqttPublisher(broker.target, edge_id="sim", rovers=ids, client_id=f"edge-ips-sim-{config.seed}")
    fleet: Fleet | None = None
    formation = None
    started = time.monotonic()
    try:
        publisher.start()
        if not publisher.wait_connected(10.0):
            raise SimulationError(f"broker {broker.target.display()}: the publisher could not connect within 10 s")
        if config.formation:
            message = formation_message(config.kind, ids, config.bar)
            formation = message.model_dump()
            if not publisher.publish(FORMATION_TOPIC, dumps(message), qos=1, retain=True):
                raise SimulationError("the formation could not be published")
            fleet = Fleet(configs, broker.target, config.link, config.seed, lambda: clock.now_s)
            fleet.join(message.seq)
        parts = LoopParts(world, camera_path, publisher, fleet, broker, clock)
        loop = ClosedLoop(config, parts, LoopHooks(on_frame, progress, video), n_frames)
        loop.run()
    finally:
        if fleet is not None:
            fleet.close()
        publisher.stop()
        broker.close()
    record = loop.record(int(publisher.stats.poses_dropped))
    record.formation = formation
    record.plans = plans
    record.wall_s = time.monotonic() - started
    return record
