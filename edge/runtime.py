"""The appliance's main job: frames in, poses out, for weeks.

Threads and what they share:

* ``capture`` (:class:`edge.sources.CaptureThread`) reads the source into a newest-frame :class:`FrameSlot`;
* ``tracker`` (:class:`EdgeRuntime`) takes the newest frame, runs the tracker, publishes one pose per rover;
* ``status`` publishes the retained edge status every ``status_interval_s`` and at once after a reconnect;
* paho's network thread (reconnects with backoff), the recorder's writer, the HTTP server, the embedded broker.

They talk through the slot, ``threading.Event`` for stop, and the recorder's bounded queue. Stopping publishes
the ``offline`` status, waits for the broker's acknowledgement, then flushes the recording.

:func:`prepare_appliance` assembles everything from an :class:`EdgeConfig`, failing before anything starts when
the camera, calibration, ports or broker credentials are wrong.
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from edge.config import BrokerTarget, EdgeConfig, broker_target
from edge.errors import CalibrationError, MessageError
from edge.messages import StatusV1, encode_pose
from edge.metrics import Latency, LatencyWindow, RateMeter, RoverSnapshot, Snapshot
from edge.publisher import MqttPublisher, Publisher, TlsFiles, offline_status
from edge.sources import CaptureThread, FrameSlot, FrameSource, SourceInfo, make_source, parse_source
from edge.tracking import Frame, FrameResult, Tracker

if TYPE_CHECKING:
    from edge.calibration import Calibration
    from edge.camera import PinholeCamera

log = logging.getLogger("edge.runtime")


class _RoverStats:
    __slots__ = ("detections", "id", "last", "last_seen_mono", "missed", "rate", "seq")

    def __init__(self, rover_id: str) -> None:
        self.id = rover_id
        self.seq = 0
        self.detections = 0
        self.missed = 0
        self.last_seen_mono: float | None = None
        self.last: tuple[float, float, float | None, float] | None = None  # x_cm, y_cm, theta_rad, quality
        self.rate = RateMeter()


class EdgeRuntime:
    """Source -> tracker -> publisher, on threads, with status, metrics and a clean stop.

    ``source`` must already be open (``info`` is what it granted). ``tap`` is not needed here: recording hangs
    off the publisher.
    """

    def __init__(
        self,
        *,
        edge_id: str,
        source: FrameSource,
        info: SourceInfo,
        tracker: Tracker,
        publisher: Publisher,
        rovers: Sequence[str],
        broker_display: str = "",
        status_interval_s: float = 2.0,
        stall_timeout_s: float = 2.0,
        reopen_min_s: float = 0.5,
        reopen_max_s: float = 8.0,
        recorder: Any = None,
    ) -> None:
        self.edge_id = edge_id
        self.info = info
        self.tracker = tracker
        self.publisher = publisher
        self.rover_ids = tuple(rovers)
        self.broker_display = broker_display
        self.status_interval_s = status_interval_s
        self.stall_timeout_s = stall_timeout_s
        self.recorder = recorder
        self.stop_event = threading.Event()
        self.slot = FrameSlot()
        self.capture = CaptureThread(
            source, self.slot, self.stop_event, info=info, reopen_min_s=reopen_min_s, reopen_max_s=reopen_max_s
        )
        self.processing = LatencyWindow()
        self.end_to_end = LatencyWindow()
        self.fps_meter = RateMeter()
        self.frames_processed = 0
        self.poses_invalid = 0
        self.latest_result: FrameResult | None = None
        self.last_frame: Frame | None = None  # the frame latest_result came from (the dashboard encodes it)
        self._tracked = threading.Condition()
        self._first_result_mono: float | None = None
        self.error: BaseException | None = None
        self._rovers = {r: _RoverStats(r) for r in self.rover_ids}
        self._status_due = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started_mono = time.monotonic()
        self._last_state: tuple[str, str] = ("", "")
        self._stopped = False

    # -- the hot path -------------------------------------------------------------------------------------------
    def _publish_result(self, result: FrameResult, frame_index: int, t_capture_s: float) -> None:
        seen = set()
        for est in result.estimates:
            stats = self._rovers.get(est.rover_id)
            if stats is None:
                continue  # the tracker knows a rover the configuration does not: nobody subscribed for it
            seen.add(est.rover_id)
            try:
                payload = encode_pose(
                    est.rover_id,
                    stats.seq,
                    frame_index,
                    t_capture_s,
                    est.x_cm,
                    est.y_cm,
                    est.theta_rad,
                    est.vx_cm_s,
                    est.vy_cm_s,
                    est.quality,
                )
            except MessageError as exc:
                self.poses_invalid += 1
                if self.poses_invalid in (1, 10, 100, 1000) or self.poses_invalid % 10000 == 0:
                    log.warning("pose not publishable (%d so far): %s", self.poses_invalid, exc)
                continue
            if self.publisher.publish_pose(est.rover_id, payload):
                stats.seq += 1
            stats.detections += 1
            stats.last_seen_mono = result.t_mono_s
            stats.last = (est.x_cm, est.y_cm, est.theta_rad, est.quality)
            stats.rate.tick(result.t_mono_s)
        for rover_id, stats in self._rovers.items():
            if rover_id not in seen:
                stats.missed += 1

    def _track(self) -> None:
        while not self.stop_event.is_set():
            frame = self.slot.take(timeout_s=0.25)
            if frame is None:
                if self.slot.closed:
                    break
                continue
            t0 = time.monotonic()
            result = self.tracker.process(frame)
            t1 = time.monotonic()
            self._publish_result(result, frame.index, frame.t_capture_s)
            t2 = time.monotonic()
            self.processing.add(t1 - t0)
            self.end_to_end.add(t2 - frame.t_mono_s)
            self.fps_meter.tick(t2)
            self.frames_processed += 1
            self.last_frame = frame
            self.latest_result = result
            with self._tracked:
                self._tracked.notify_all()
            if self._first_result_mono is None:
                self._first_result_mono = t2

    def wait_tracked(self, timeout_s: float) -> None:
        """Block until the tracker has finished its next frame (or ``timeout_s``): the dashboard's threads do their
        work in the gap that follows, not beside the tracker."""
        with self._tracked:
            self._tracked.wait(timeout_s)

    def _run_guarded(self, target: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                target()
            except BaseException as exc:
                self.error = exc
                log.error("%s thread failed: %s: %s", threading.current_thread().name, type(exc).__name__, exc)
                self.stop_event.set()
            finally:
                self._status_due.set()

        return run

    # -- status -------------------------------------------------------------------------------------------------
    def camera_state(self) -> str:
        if self.capture.state != "ok":
            return self.capture.state
        if self.capture.frames == 0:
            return "starting" if time.monotonic() - self._started_mono < self.stall_timeout_s else "stalled"
        if time.monotonic() - self.capture.last_frame_mono > self.stall_timeout_s:
            return "stalled"
        return "ok"

    def _seen_recently(self, now: float) -> tuple[list[str], list[str]]:
        window = max(self.status_interval_s, 1.0)
        seen: list[str] = []
        missing: list[str] = []
        for rover_id, stats in self._rovers.items():
            fresh = stats.last_seen_mono is not None and now - stats.last_seen_mono <= window
            (seen if fresh else missing).append(rover_id)
        return seen, missing

    def _state(self, camera: str, missing: list[str]) -> tuple[str, str]:
        if camera not in ("ok", "starting"):
            return "degraded", f"camera {camera}"
        tracking_for_s = 0.0 if self._first_result_mono is None else time.monotonic() - self._first_result_mono
        if camera == "ok" and missing and tracking_for_s > max(self.status_interval_s, 1.0):
            return "degraded", f"not seen: {', '.join(missing)}"
        return "online", ""

    def current_status(self) -> StatusV1:
        now = time.monotonic()
        camera = self.camera_state()
        seen, missing = self._seen_recently(now)
        state, reason = self._state(camera, missing)
        if (state, reason) != self._last_state:
            level = logging.INFO if state == "online" else logging.WARNING
            log.log(level, "status %s%s", state, f" ({reason})" if reason else "")
            self._last_state = (state, reason)
        return StatusV1(
            v=1,
            edge=self.edge_id,
            state=state,  # type: ignore[arg-type]
            camera=camera,  # type: ignore[arg-type]
            fps=round(min(self.fps_meter.rate(now), 1000.0), 2),
            rovers=seen,
            missing=missing,
            t=round(time.time(), 3),
        )

    def _status_loop(self) -> None:
        while not self.stop_event.is_set():
            self.publisher.publish_status(self.current_status())
            self._status_due.wait(self.status_interval_s)
            self._status_due.clear()

    def status_now(self) -> None:
        """Publish a fresh status soon (after a reconnect)."""
        self._status_due.set()

    # -- life cycle ---------------------------------------------------------------------------------------------
    def start(self) -> EdgeRuntime:
        self._started_mono = time.monotonic()
        self.capture.start()
        for name, target in (("tracker", self._track), ("status", self._status_loop)):
            thread = threading.Thread(target=self._run_guarded(target), name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    @property
    def finished(self) -> bool:
        """True when the source ended, a thread failed, or stop was asked for."""
        return self.stop_event.is_set() or not self._threads[0].is_alive()

    def wait(self, stop: threading.Event) -> None:
        """Block until ``stop`` is set or the runtime finishes by itself."""
        while not stop.wait(0.2):
            if self.finished:
                break
        if self.capture.error is not None and self.error is None:
            self.error = self.capture.error

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop capture and tracking, publish ``offline``, disconnect, flush the recording. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self.stop_event.set()
        self._status_due.set()
        self.slot.close()
        for thread in self._threads:
            thread.join(timeout=timeout_s)
        self.capture.join(timeout=timeout_s)
        self.publisher.stop(offline_status(self.edge_id, self.rover_ids), timeout_s=timeout_s)
        if self.recorder is not None:
            self.recorder.close()
        log.info("stopped after %d frames; offline status published", self.frames_processed)

    # -- for /metrics, /healthz and the dashboard ---------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        now = time.monotonic()
        camera = self.camera_state() if not self._stopped else "stopped"
        _, missing = self._seen_recently(now)
        state, reason = self._state(camera, missing) if not self._stopped else ("offline", "stopped")
        rovers = tuple(
            RoverSnapshot(
                id=s.id,
                detections=s.detections,
                missed=s.missed,
                last_seen_age_s=None if s.last_seen_mono is None else now - s.last_seen_mono,
                rate_hz=s.rate.rate(now),
                quality=None if s.last is None else s.last[3],
                x_cm=None if s.last is None else s.last[0],
                y_cm=None if s.last is None else s.last[1],
                theta_rad=None if s.last is None else s.last[2],
            )
            for s in self._rovers.values()
        )
        stats = self.publisher.stats
        return Snapshot(
            edge_id=self.edge_id,
            state=state,
            reason=reason,
            camera=camera,
            source=self.capture.info.description,
            broker=self.broker_display,
            uptime_s=now - self._started_mono,
            fps=self.fps_meter.rate(now),
            frames_processed=self.frames_processed,
            frames_dropped=self.slot.overwritten,
            processing=Latency.of(self.processing),
            end_to_end=Latency.of(self.end_to_end),
            rovers=rovers,
            broker_connected=self.publisher.connected,
            broker_connects=stats.connects,
            broker_disconnects=stats.disconnects,
            poses_sent=stats.poses_sent,
            poses_dropped=stats.poses_dropped,
            poses_invalid=self.poses_invalid,
            camera_failures=self.capture.failures,
            camera_reopens=self.capture.reopens,
            recording_lines=0 if self.recorder is None else self.recorder.lines_written,
            recording_dropped=0 if self.recorder is None else self.recorder.lines_dropped,
        )


# -- assembling the appliance from its configuration -------------------------------------------------------------
@dataclass(frozen=True)
class TrackerInputs:
    """What a tracker factory gets: the configuration, the opened source, what it granted, the calibration."""

    config: EdgeConfig
    source: FrameSource
    info: SourceInfo
    calibration: Any


TrackerFactory = Callable[[TrackerInputs], Tracker]
SimFactory = Callable[[str], FrameSource]


def default_sim_factory(config: EdgeConfig) -> SimFactory:
    """The simulator's source (issue 4), paced in real time, for ``--source sim[:SCENARIO]``."""

    def make(scenario: str) -> FrameSource:
        from edge.sim.source import SimSource

        return SimSource(scenario or "lab", seed=0, realtime=config.camera.realtime)

    return make


def default_tracker_factory(inputs: TrackerInputs) -> Tracker:
    """The tracking pipeline (issue 5) built from the rovers, the ``[tracker]`` settings and the calibration."""
    from edge.tracker_config import TrackerConfig
    from edge.trackers.factory import build_tracker

    return build_tracker(TrackerConfig.of(inputs.config.tracker, inputs.config.rovers), inputs.calibration)


def _with_sim_rovers(config: EdgeConfig, source: FrameSource) -> EdgeConfig:
    """With the simulated camera and no rovers configured, track the simulator's rovers in its colours."""
    from edge.tracker_config import DEFAULT_ROVERS

    own = getattr(source, "rover_configs", None)
    if parse_source(config.camera.source).kind != "sim" or not callable(own) or config.rovers != list(DEFAULT_ROVERS):
        return config
    rovers = list(own())
    log.info("rovers: the simulator's, %s", ", ".join(f"{r.id} {r.color_bgr}" for r in rovers))
    return config.model_copy(update={"rovers": rovers})


def exact_calibration(camera: PinholeCamera, z_cm: float | None = None) -> Calibration:
    """The exact :class:`edge.calibration.Calibration` of a known camera (the simulator's) on the marker plane."""
    from edge.calibration import Calibration, Intrinsics
    from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM

    z = MARKER_HEIGHT_CM if z_cm is None else z_cm
    lens = Intrinsics(camera.camera_matrix, camera.dist_coeffs, camera.width_px, camera.height_px)
    return Calibration(
        camera.plane_homography(z),
        camera.width_px,
        camera.height_px,
        z,
        (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM),
        lens,
        camera,
    )


def load_calibration_for(config: EdgeConfig, source: FrameSource, info: SourceInfo, where: str) -> Calibration:
    """The calibration for a real source (required), or the simulator's own exact one (from its camera)."""
    if parse_source(config.camera.source).kind == "sim":
        camera = getattr(getattr(source, "setup", None), "camera", None) or getattr(source, "camera", None)
        if camera is None:
            raise CalibrationError("the simulated camera does not expose its camera model")
        return exact_calibration(camera)
    path = config.calibration.path
    if path is None:
        raise CalibrationError(
            f"no calibration configured: set calibration.path in {where} (make one with `edge-ips calibrate`), "
            "or use --source sim"
        )
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found (calibration.path in {where})")
    from edge.calibration import load_calibration

    return load_calibration(path, expected_size=(info.width_px, info.height_px))


CalibrationLoader = Callable[[EdgeConfig, FrameSource, SourceInfo, str], Any]


@dataclass
class Appliance:
    """Everything ``edge-ips start`` runs, assembled and checked; :meth:`run` until ``stop`` is set."""

    runtime: EdgeRuntime
    target: BrokerTarget
    broker: Any = None
    http: Any = None
    dashboard: Any = None

    def run(self, stop: threading.Event) -> None:
        self.runtime.start()
        try:
            self.runtime.wait(stop)
        finally:
            self.close()
        if self.runtime.error is not None:
            raise self.runtime.error

    def close(self) -> None:
        """Stop the runtime (offline status, recording flushed), then the HTTP server and the embedded broker."""
        self.runtime.stop()
        if self.dashboard is not None:
            self.dashboard.close()
        if self.http is not None:
            self.http.stop()
        if self.broker is not None:
            self.broker.stop()


def prepare_appliance(
    config: EdgeConfig,
    *,
    config_where: str = "the configuration",
    tracker_factory: TrackerFactory = default_tracker_factory,
    sim_factory: SimFactory | None = None,
    calibration_loader: CalibrationLoader | None = None,
    connect_timeout_s: float = 3.0,
) -> Appliance:
    """Open the source, load the calibration, build the tracker, bind the ports, start the broker, connect.

    Every user-fixable problem raises an :class:`EdgeIpsError` here, before any frame is published; whatever was
    already started is stopped again.
    """
    from edge.broker import EmbeddedBroker
    from edge.httpserver import HttpServer, Response
    from edge.metrics import to_prometheus
    from edge.recording import Recorder

    cam = config.camera
    tls = TlsFiles(config.broker.ca_file, config.broker.cert_file, config.broker.key_file)
    if broker_target(config.broker).tls:
        tls.check()
    with contextlib.ExitStack() as started:
        # The source, its calibration and the tracker first: a missing camera or a bad calibration is said before
        # any port is bound (and not hidden behind a port that is taken).
        source = make_source(
            cam.source,
            width=cam.width,
            height=cam.height,
            fps=cam.fps,
            fourcc=cam.fourcc,
            loop=cam.loop,
            realtime=cam.realtime,
            stall_timeout_s=cam.stall_timeout_s,
            sim_factory=sim_factory or default_sim_factory(config),
        )
        info = source.open()
        started.callback(source.close)
        log.info("source: %s", info.description)
        config = _with_sim_rovers(config, source)
        calibration = (calibration_loader or load_calibration_for)(config, source, info, config_where)
        tracker = tracker_factory(TrackerInputs(config, source, info, calibration))

        http = None
        if config.http.enabled:
            http = HttpServer(config.http.host, config.http.port).start()
            started.callback(http.stop)

        target = broker_target(config.broker)
        broker = None
        if target.embedded:
            broker = EmbeddedBroker(target.host, target.port).start()
            started.callback(broker.stop)
            target = BrokerTarget(embedded=True, host=target.host, port=broker.port)

        recorder = None
        if config.recording.dir is not None:
            recorder = Recorder(
                config.recording.dir, max_bytes=config.recording.max_bytes, max_files=config.recording.max_files
            ).start()
            started.callback(recorder.close)
            log.info("recording everything published to %s", config.recording.dir)

        rovers = [r.id for r in config.rovers]
        runtime_ref: list[EdgeRuntime] = []
        publisher = MqttPublisher(
            target,
            edge_id=config.edge.id,
            rovers=rovers,
            client_id=config.broker.client_id,
            keepalive_s=config.broker.keepalive_s,
            reconnect_min_s=config.broker.reconnect_min_s,
            reconnect_max_s=config.broker.reconnect_max_s,
            tls=tls,
            tap=recorder.record if recorder is not None else None,
            on_connected=lambda: runtime_ref[0].status_now() if runtime_ref else None,
        )
        publisher.start()
        started.callback(publisher.stop)
        if not publisher.wait_connected(connect_timeout_s):
            log.warning("broker %s not reachable yet; retrying in the background", target.display())

        runtime = EdgeRuntime(
            edge_id=config.edge.id,
            source=source,
            info=info,
            tracker=tracker,
            publisher=publisher,
            rovers=rovers,
            broker_display=target.display(),
            status_interval_s=config.edge.status_interval_s,
            stall_timeout_s=cam.stall_timeout_s,
            reopen_min_s=cam.reopen_min_s,
            reopen_max_s=cam.reopen_max_s,
            recorder=recorder,
        )
        runtime_ref.append(runtime)
        if http is not None:
            http.route("/healthz", lambda request: _health(runtime))
            http.route(
                "/metrics",
                lambda request: Response(
                    body=to_prometheus(runtime.snapshot()).encode(),
                    content_type="text/plain; version=0.0.4; charset=utf-8",
                ),
            )
        dashboard = None
        if http is not None and config.dashboard.enabled:
            from edge.dashboard import start_dashboard

            dashboard = start_dashboard(config, runtime, http, calibration=calibration, target=target, tls=tls)
            started.callback(dashboard.close)
            log.info("dashboard on http://%s:%d/", _display_host(http.host), http.port)
        started.pop_all()  # all checks passed: the appliance owns what was started
    return Appliance(runtime=runtime, target=target, broker=broker, http=http, dashboard=dashboard)


def _display_host(host: str) -> str:
    return "localhost" if host in ("0.0.0.0", "::", "") else host


def run_until_signalled(appliance: Appliance) -> None:
    """Run until SIGTERM or SIGINT (call from the main thread), then stop cleanly."""
    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        if not stop.is_set():  # a signal sent to the process and to its group arrives twice
            log.info("%s received: stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    appliance.run(stop)


def _health(runtime: EdgeRuntime) -> Any:
    from edge.httpserver import Response

    snap = runtime.snapshot()
    body = json.dumps(snap.health()).encode() + b"\n"
    return Response(200 if snap.state == "online" else 503, body, "application/json")
