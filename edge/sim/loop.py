"""The closed loop of issue 8: simulated rovers, a rendered camera, the edge's tracker, MQTT, the rovers' firmware.

::

    World (differential drive: wheel limits, gain error, noise, delay)
      -> Renderer (the paper's lab as the webcam sees it)                      every 1/30 s of simulated time
      -> edge.pipeline.Pipeline (the tracker `edge-ips start` runs)
      -> edge.publisher.MqttPublisher -> a real broker (embedded amqtt, or Mosquitto at --broker URL)
      -> one edge.rover_host.HostRover per rover (the firmware's real modules; host stand-ins for machine/network)
      -> PWM duties -> wheel speeds (the duty model inverted) -> World                   every 20 ms (the firmware)

Time: the world, the camera and the firmware run on one simulated clock (integer microseconds). A frame captured at
``t`` is published ``latency_ms`` later on that clock (readout, USB, tracking); its poses then cross the broker in
real time, and each rover is given a bounded real-time window (``deliver_timeout_s``) to receive them before the
simulated clock moves on. A pose that misses the window is *late*: the rover gets it at a later step, or never,
and drives on what it has, as a real rover would. Nothing is bypassed: a frame the tracker misreads, a pose the
publisher drops while disconnected, a late message, all reach the rovers' behaviour.

Scripted runs (``edge-ips sim trajectory``) follow :mod:`edge.sim.trajectories` plans instead of the firmware; the
poses still go through the tracker, the publisher and the broker.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, PinholeCamera, paper_camera
from edge.errors import ConfigError, SimulationError
from edge.messages import FORMATION_TOPIC, MessageError, dumps, encode_pose
from edge.sim.metrics import FORMATIONS, Bar
from edge.sim.rover import (
    BODY_LENGTH_CM,
    BODY_WIDTH_CM,
    MotorPhysics,
    fleet_drive_model,
    fleet_ids,
    rover_config,
    rover_looks,
)
from edge.sim.scene import Heading, Scene
from edge.sim.world import Plan, Pose, WheelCommand, World, WorldState
from edge.sources import Frame

TRAJECTORIES = ("circle", "diagonal")
FPS = 30.0
US = 1_000_000
SNAPSHOT_EVERY = 15  # frames kept (downscaled) for the snapshot figure


@dataclass(frozen=True)
class LoopConfig:
    """One closed-loop run.

    ``kind``: a formation (line, rendezvous, triangle) or a trajectory (circle, diagonal). ``broker_url``: None
    for the embedded broker, else ``mqtt://host:port``. ``feed_stop_frame``: the camera feed stops at this frame
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


# -- starting layouts and scripted paths ---------------------------------------------------------------------------
def random_layout(
    n: int, rng: np.random.Generator, min_gap_cm: float = 150.0, margin_cm: float = 40.0, tries: int = 10000
) -> list[Pose]:
    """``n`` starts uniformly in the working area (``margin_cm`` from its edge), pairwise at least ``min_gap_cm``
    apart, with random headings. All ``n`` are drawn at once and redrawn until they are apart; when that keeps
    failing (a crowded area), they are placed one by one, each where it is clear of those already placed."""
    lo = np.array([margin_cm, margin_cm])
    hi = np.array([AREA_WIDTH_CM - margin_cm, AREA_LENGTH_CM - margin_cm])
    for _ in range(tries if n <= 6 else 200):
        xy = np.column_stack(
            [
                rng.uniform(margin_cm, AREA_WIDTH_CM - margin_cm, n),
                rng.uniform(margin_cm, AREA_LENGTH_CM - margin_cm, n),
            ]
        )
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        d[np.diag_indices(n)] = np.inf
        if n < 2 or d.min() >= min_gap_cm:
            headings = rng.uniform(-math.pi, math.pi, n)
            return [Pose(float(x), float(y), float(h)) for (x, y), h in zip(xy, headings, strict=True)]
    for _ in range(200):
        placed: list[NDArray[np.float64]] = []
        for _ in range(n):
            for _ in range(500):
                p = rng.uniform(lo, hi)
                if all(math.hypot(*(p - q)) >= min_gap_cm for q in placed):
                    placed.append(p)
                    break
            else:
                break
        if len(placed) == n:
            headings = rng.uniform(-math.pi, math.pi, n)
            return [Pose(float(p[0]), float(p[1]), float(h)) for p, h in zip(placed, headings, strict=True)]
    raise SimulationError(f"no layout of {n} rovers {min_gap_cm:g} cm apart fits in the working area")


def trajectory_plans(kind: str, n: int, rng: np.random.Generator) -> list[Plan]:
    """Scripted paths of the paper's trajectory tests: ``circle`` (Figs. 33-36: each rover 1.75 laps round its own
    circle) and ``diagonal`` (Fig. 37-38: from near (0, 0) towards (391.5, 549.5), side by side)."""
    from edge.sim.trajectories import circle, diagonal

    if kind == "circle":
        centres = [(110.0, 150.0), (280.0, 280.0), (110.0, 410.0), (280.0, 110.0), (280.0, 450.0), (110.0, 280.0)]
        if n > len(centres):
            raise ConfigError(f"the circle test has room for {len(centres)} rovers, got {n}")
        return [
            circle(
                (cx + float(rng.uniform(-10, 10)), cy + float(rng.uniform(-10, 10))),
                float(rng.uniform(55.0, 65.0)),
                laps=1.75,
                speed_cm_s=float(rng.uniform(18.0, 24.0)),
                start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
                ccw=bool(k % 2 == 0),
            )
            for k, (cx, cy) in enumerate(centres[:n])
        ]
    if kind == "diagonal":
        if n > 5:
            raise ConfigError(f"the diagonal test has room for 5 rovers, got {n}")
        length = math.hypot(AREA_WIDTH_CM, AREA_LENGTH_CM)
        ex, ey = AREA_WIDTH_CM / length, AREA_LENGTH_CM / length
        nx, ny = -ey, ex  # across the diagonal
        margin = 30.0
        plans = []
        for k in range(n):
            off = (k - (n - 1) / 2) * 45.0  # 45 cm lanes: the 17.2 cm bodies never meet
            cx, cy = AREA_WIDTH_CM / 2 + off * nx, AREA_LENGTH_CM / 2 + off * ny
            # the stretch of this lane inside the area less the margin
            lo, hi = -math.inf, math.inf
            for c, e, size in ((cx, ex, AREA_WIDTH_CM), (cy, ey, AREA_LENGTH_CM)):
                a, b = (margin - c) / e, (size - margin - c) / e
                lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
            plans.append(
                diagonal(
                    (cx + lo * ex, cy + lo * ey),
                    (cx + hi * ex, cy + hi * ey),
                    speed_cm_s=float(rng.uniform(22.0, 28.0)),
                    wait_before_s=1.0 + 0.5 * k,
                )
            )
        return plans
    raise ConfigError(f"unknown trajectory {kind!r}: use circle or diagonal")


# -- what a run records --------------------------------------------------------------------------------------------
@dataclass
class MotorLog:
    """Every firmware step of one rover: time (ms, simulated), duties, directions, halt reason."""

    t_ms: list[int] = field(default_factory=list)
    left_duty: list[int] = field(default_factory=list)
    right_duty: list[int] = field(default_factory=list)
    left_forward: list[bool] = field(default_factory=list)
    right_forward: list[bool] = field(default_factory=list)
    halt: list[str] = field(default_factory=list)


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
    deliveries_late: dict[str, int]  # rover -> frames whose poses missed the delivery window
    poses_dropped: int  # not handed to the broker (publisher disconnected)
    snapshots: dict[int, NDArray[np.uint8]]  # frame -> downscaled camera image
    overlays: dict[int, list[tuple[str, float, float]]]  # frame -> (id, u, v) of the tracker's estimates, full-res px
    formation: dict[str, Any] | None
    plans: dict[str, Plan] | None
    wall_s: float = 0.0
    frames_tracked: int = 0


# -- the pieces ----------------------------------------------------------------------------------------------------
class _Broker:
    """The broker the run talks through: the embedded amqtt broker (started here), or one at a URL."""

    def __init__(self, url: str | None) -> None:
        from edge.config import BrokerTarget, parse_broker_url

        self._embedded: Any = None
        if url is None:
            from edge.broker import EmbeddedBroker

            self._embedded = EmbeddedBroker("127.0.0.1", 0).start()
            self.target = BrokerTarget(embedded=False, host="127.0.0.1", port=self._embedded.port)
        else:
            try:
                self.target = parse_broker_url(url)
            except ValueError as exc:
                raise ConfigError(f"--broker: {exc}") from None
            if self.target.embedded:
                from edge.broker import EmbeddedBroker

                self._embedded = EmbeddedBroker("127.0.0.1", 0).start()
                self.target = BrokerTarget(embedded=False, host="127.0.0.1", port=self._embedded.port)

    def kill(self) -> bool:
        """Stop the embedded broker (True); a broker at a URL is not ours to stop (False)."""
        if self._embedded is None:
            return False
        self._embedded.stop(timeout_s=5.0)
        return True

    def close(self) -> None:
        self.kill()


def marker_colors(
    camera: PinholeCamera, scene: Scene, effects: Any, seed: int
) -> dict[str, tuple[tuple[int, int, int], tuple[int, int, int] | None]]:
    """Each rover's marker colour, and its front colour (two-tone), as the camera sees them: measured on a frame of
    the rovers standing in the middle of the area, the way an installer picks them from a live picture."""
    from edge.sim.render import Renderer
    from edge.sim.world import RoverState

    renderer = Renderer(camera, scene, effects, seed=seed + 7919, fps=FPS)
    out: dict[str, tuple[tuple[int, int, int], tuple[int, int, int] | None]] = {}
    looks = scene.rovers
    for k, look in enumerate(looks):
        x = AREA_WIDTH_CM / 2
        y = AREA_LENGTH_CM / 2
        state = WorldState(0.0, (RoverState(look.rover_id, x, y, 0.0, 0.0, 0.0),))
        image = renderer.render(state, k)
        main_xy = [x - 0.25 * look.marker_length_cm * look.front_fraction, y]
        main = _sample(image, camera, main_xy, look.body_height_cm)
        front = None
        if look.heading == "two_tone":
            front_x = x + 0.5 * look.marker_length_cm * (1.0 - look.front_fraction)
            front = _sample(image, camera, [front_x, y], look.body_height_cm)
        out[look.rover_id] = (main, front)
    return out


def _sample(
    image: NDArray[np.uint8], camera: PinholeCamera, xy_cm: Sequence[float], z_cm: float
) -> tuple[int, int, int]:
    u, v = camera.project(np.array([[xy_cm[0], xy_cm[1], z_cm]]))[0]
    ui, vi = round(float(u)), round(float(v))
    patch = image[vi - 1 : vi + 2, ui - 1 : ui + 2].reshape(-1, 3)
    b, g, r = (round(float(c)) for c in np.median(patch, axis=0))
    return b, g, r


def build_tracker(camera: PinholeCamera, scene: Scene, effects: Any, seed: int) -> Any:
    """The tracker `edge-ips start` runs on the simulated camera: :class:`edge.pipeline.Pipeline` with the default
    settings, the rovers' measured colours and the camera's exact calibration."""
    # (the ignores: Pipeline, TrackerConfig and the two-tone fields land with the tracker's branch)
    from edge.calibration.exact import exact_calibration
    from edge.pipeline import Pipeline, RoverConfig, TrackerConfig  # type: ignore[attr-defined,unused-ignore]

    colors = marker_colors(camera, scene, effects, seed)
    rovers = tuple(
        RoverConfig(  # type: ignore[call-arg,unused-ignore]
            id=rid, color_bgr=main, front_color_bgr=front, front_fraction=scene.look(rid).front_fraction
        )
        for rid, (main, front) in colors.items()
    )
    return Pipeline(TrackerConfig(rovers=rovers), exact_calibration(camera))


def formation_message(kind: str, ids: Sequence[str], bar: Bar, seq: int = 1) -> Any:
    """The retained formation the edge publishes: the paper's vertical line (``theta`` null: either end), a
    rendezvous, a triangle of ``side_cm``; free to settle anywhere (no ``x``/``y`` anchor)."""
    from edge.commands import build_formation

    if kind == "line":
        return build_formation("line", ids, seq=seq, spacing_cm=bar.spacing_cm)
    if kind == "triangle":
        return build_formation("triangle", ids, seq=seq, side_cm=bar.side_cm)
    return build_formation("rendezvous", ids, seq=seq)


# -- the run -------------------------------------------------------------------------------------------------------
def run(
    config: LoopConfig,
    *,
    on_frame: Callable[[int], None] | None = None,
    progress: Callable[[int], None] | None = None,
    video: Callable[[NDArray[np.uint8]], None] | None = None,
) -> LoopRecord:
    """Run one experiment end to end and return what it recorded. ``on_frame(k)`` is called before frame ``k`` is
    captured (a test kills a broker there); ``progress(k)`` after it; ``video(image)`` gets every tracked frame
    annotated with the tracker's estimates."""
    from edge.publisher import MqttPublisher
    from edge.rover_host import HostRover
    from edge.sim.render import Renderer
    from edge.sim.scenarios import _rng, lab_effects

    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x100B]))
    ids = fleet_ids(config.rovers)
    configs = [rover_config(rid) for rid in ids]
    drive = fleet_drive_model(configs, config.physics)
    camera = paper_camera()
    looks = rover_looks(configs, config.heading)
    scene = Scene(looks)
    effects = lab_effects(_rng("lab", config.seed))
    plans: dict[str, Plan] | None = None
    n_frames = config.n_frames
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
    renderer = Renderer(camera, scene, effects, seed=config.seed, fps=FPS)
    tracker = build_tracker(camera, scene, effects, config.seed)

    broker = _Broker(config.broker_url)
    published: list[tuple[int, str, bytes]] = []
    publisher = MqttPublisher(broker.target, edge_id="sim", rovers=ids, client_id=f"edge-ips-sim-{config.seed}")
    rovers: dict[str, Any] = {}
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
            for cfg in configs:
                rovers[cfg["id"]] = HostRover(cfg, broker.target.host, broker.target.port)
            for rid, hr in rovers.items():
                hr.step(0)
                if not hr.pump(lambda hr=hr: _applied(hr, message.seq), timeout_s=10.0):
                    raise SimulationError(f"rover {rid} did not receive the formation within 10 s")
        record = _loop(
            config,
            ids,
            world,
            renderer,
            tracker,
            publisher,
            broker,
            rovers,
            n_frames,
            on_frame,
            progress,
            published,
            video,
        )
    finally:
        for hr in rovers.values():
            hr.close()
        publisher.stop()
        broker.close()
    record.camera = camera
    record.formation = formation
    record.plans = plans
    record.wall_s = time.monotonic() - started
    return record


def _applied(hr: Any, seq: int) -> bool:
    return _formation_seq(hr) == seq


def _formation_seq(hr: Any) -> int | None:
    from edge.rover_host import firmware_modules

    f = hr.rover.formation
    if f is None:
        return None
    return int(f[firmware_modules()["msg"].F_SEQ])


def _has_seen(hr: Any, sent: Mapping[str, int]) -> bool:
    """True when the rover has received every pose of ``sent`` (rover id -> seq) or a newer one."""
    for rid, want in sent.items():
        got = hr.last_seq(rid)
        if got is None or got < want:
            return False
    return True


def _loop(
    config: LoopConfig,
    ids: tuple[str, ...],
    world: World,
    renderer: Any,
    tracker: Any,
    publisher: Any,
    broker: _Broker,
    rovers: Mapping[str, Any],
    n_frames: int,
    on_frame: Callable[[int], None] | None,
    progress: Callable[[int], None] | None,
    published: list[tuple[int, str, bytes]],
    video: Callable[[NDArray[np.uint8]], None] | None,
) -> LoopRecord:
    n = len(ids)
    index = {rid: k for k, rid in enumerate(ids)}
    truth = np.full((n_frames, n, 3), np.nan)
    measured = np.full((n_frames, n, 3), np.nan)
    motors = {rid: MotorLog() for rid in rovers}
    fresh: dict[str, list[int]] = {rid: [] for rid in rovers}
    own_seq: dict[str, int | None] = {rid: None for rid in rovers}
    late = {rid: 0 for rid in rovers}
    seq = {rid: 0 for rid in ids}
    snapshots: dict[int, NDArray[np.uint8]] = {}
    overlays: dict[int, list[tuple[str, float, float]]] = {}
    period_us = int(next(iter(rovers.values())).config["control"]["period_ms"]) * 1000 if rovers else 10**12
    latency_us = round(config.latency_ms * 1000)
    pending: deque[tuple[int, int, float, list[Any]]] = deque()  # (due us, frame, capture time, estimates)
    wall0 = time.time()
    frame_k = 0
    step_j = 1  # the firmware stepped once at t = 0 when it got the formation
    frames_tracked = 0
    commands: dict[str, WheelCommand] = {}
    now_us = 0

    def check_fresh(t_ms: int) -> None:
        for rid, hr in rovers.items():
            s = hr.last_seq(rid)
            if s is not None and s != own_seq[rid]:
                own_seq[rid] = s
                fresh[rid].append(t_ms)

    while frame_k < n_frames or pending:
        t_frame = round(frame_k * US / FPS) if frame_k < n_frames else math.inf
        t_step = step_j * period_us if rovers else math.inf
        t_deliver = pending[0][0] if pending else math.inf
        t_next = min(t_frame, t_step, t_deliver)
        if frame_k >= n_frames and not pending:
            break
        t_next_us = int(t_next)
        if t_next_us > now_us:
            world.step((t_next_us - now_us) / US, commands)
            commands = {}
            now_us = t_next_us
        if t_deliver == t_next:
            _, k, t_capture, estimates = pending.popleft()
            sent: dict[str, int] = {}
            for est in estimates:
                # As the runtime does (EdgeRuntime._publish_result): encode, publish, count seq only when sent.
                try:
                    payload = encode_pose(
                        est.rover_id,
                        seq[est.rover_id],
                        k,
                        t_capture,
                        est.x_cm,
                        est.y_cm,
                        est.theta_rad,
                        est.vx_cm_s,
                        est.vy_cm_s,
                        est.quality,
                    )
                except MessageError:
                    continue  # what the contract cannot carry is not sent
                if publisher.publish_pose(est.rover_id, payload):
                    published.append((k, est.rover_id, payload))
                    sent[est.rover_id] = seq[est.rover_id]
                    seq[est.rover_id] += 1
            if sent and rovers:
                t_ms = now_us // 1000
                for rid, hr in rovers.items():
                    ok = hr.pump(
                        lambda hr=hr, sent=sent: _has_seen(hr, sent),
                        timeout_s=config.deliver_timeout_s,
                        now_ms=t_ms,
                    )
                    if not ok:
                        late[rid] += 1
                check_fresh(t_ms)
        elif t_frame == t_next:
            k = frame_k
            if on_frame is not None:
                on_frame(k)
            if config.broker_stop_frame is not None and k == config.broker_stop_frame:
                broker.kill()
            state = world.state()
            for r in state.rovers:
                truth[k, index[r.rover_id]] = (r.x_cm, r.y_cm, r.theta_rad)
            feed_on = config.feed_stop_frame is None or k < config.feed_stop_frame
            if feed_on:
                image = renderer.render(state, k)
                t_s = now_us / US
                result = tracker.process(Frame(image=image, index=k, t_capture_s=wall0 + t_s, t_mono_s=t_s))
                frames_tracked += 1
                marks: list[tuple[str, float, float]] = []
                seen = []
                for est in result.estimates:
                    if est.rover_id not in index:
                        continue
                    theta = est.theta_rad if est.theta_rad is not None else math.nan
                    measured[k, index[est.rover_id]] = (est.x_cm, est.y_cm, theta)
                    marks.append((est.rover_id, float(est.uv_px[0]), float(est.uv_px[1])))
                    seen.append(est)
                pending.append((now_us + latency_us, k, wall0 + t_s, seen))
                if k % SNAPSHOT_EVERY == 0 or k == n_frames - 1:
                    snapshots[k] = image[::2, ::2].copy()
                    overlays[k] = marks
                if video is not None:
                    video(_annotate(image, marks))
            frame_k += 1
            if progress is not None:
                progress(k)
        else:
            t_ms = now_us // 1000
            for rid, hr in rovers.items():
                hr.step(t_ms)
                left, right = hr.wheel_speeds_cm_s
                commands[rid] = WheelCommand(left, right)
                m = hr.motor_state
                log = motors[rid]
                log.t_ms.append(t_ms)
                log.left_duty.append(m.left_duty)
                log.right_duty.append(m.right_duty)
                log.left_forward.append(m.left_forward)
                log.right_forward.append(m.right_forward)
                log.halt.append(hr.halt)
            check_fresh(t_ms)
            step_j += 1

    return LoopRecord(
        config=config,
        ids=ids,
        camera=renderer.camera,
        fps=FPS,
        truth=truth,
        measured=measured,
        published=published,
        motors=motors,
        fresh_ms=fresh,
        deliveries_late=late,
        poses_dropped=int(publisher.stats.poses_dropped),
        snapshots=snapshots,
        overlays=overlays,
        formation=None,
        plans=None,
        frames_tracked=frames_tracked,
    )


def _annotate(image: NDArray[np.uint8], marks: Sequence[tuple[str, float, float]]) -> NDArray[np.uint8]:
    import cv2

    out = image.copy()
    for rid, u, v in marks:
        cv2.drawMarker(out, (round(u), round(v)), (255, 255, 255), cv2.MARKER_CROSS, 18, 2)
        cv2.putText(out, rid, (round(u) + 10, round(v) - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
    return out


def body_size_cm() -> tuple[float, float]:
    """(length, width) of the simulated rover's body, for collision checks."""
    return BODY_LENGTH_CM, BODY_WIDTH_CM
