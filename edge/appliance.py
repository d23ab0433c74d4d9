"""Assembling the appliance from its configuration: what ``edge-ips start`` runs.

:func:`prepare_appliance` starts it in named steps, each a small function below, in this order:

1. :func:`open_source`: the configured camera (or the simulator), opened;
2. :func:`load_calibration_for`: its calibration (the simulator's own exact one);
3. the tracker, from ``tracker_factory``;
4. :func:`start_http`: the HTTP server, bound (before the broker: a taken port is said first);
5. :func:`start_broker`: the embedded broker, or the configured one (:func:`edge.broker.clients.select_broker`);
6. :func:`start_recorder`: the recording of everything published;
7. :func:`start_publisher`: the MQTT publisher, connected, with the retained stop at start (and at every reconnection);
8. the :class:`edge.runtime.EdgeRuntime` over all of them;
9. :func:`start_dashboard_for`, :func:`add_sim_panel` and :func:`add_health_routes`: the page, the simulator's
   controls when the source offers them, then ``/healthz`` and ``/metrics``.

Every user-fixable problem raises an :class:`edge.errors.EdgeIpsError` before any frame is published, and what
was already started is stopped again. :func:`run_until_signalled` runs the result until SIGTERM or SIGINT;
:func:`start` is ``edge-ips start``: say what runs and why, assemble, run.
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge.broker.clients import SelectedBroker, select_broker
from edge.config import BrokerTarget, EdgeConfig, broker_target
from edge.config_load import LoadedConfig
from edge.errors import CalibrationError
from edge.fusion.board import detection_builder_for
from edge.mqttclient import TlsFiles
from edge.publisher import ConnectionHold, MqttPublisher
from edge.runtime import EdgeRuntime
from edge.source_spec import SimFactory, camera_source, parse_source
from edge.sources import FrameSource, SimulatedScene, SourceInfo
from edge.tracking import Tracker

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from edge.broker.embedded import EmbeddedBroker
    from edge.calibration import Calibration
    from edge.commands import StopAtStart
    from edge.dashboard import Dashboard
    from edge.httpserver import Handler, HttpServer
    from edge.recording import Recorder

log = logging.getLogger("edge.appliance")


@dataclass(frozen=True)
class TrackerInputs:
    """What a tracker factory gets: the configuration, the opened source, what it granted, the calibration."""

    config: EdgeConfig
    source: FrameSource
    info: SourceInfo
    calibration: Any


TrackerFactory = Callable[[TrackerInputs], Tracker]
CalibrationLoader = Callable[[EdgeConfig, FrameSource, SourceInfo, str], Any]


def default_sim_factory(config: EdgeConfig) -> SimFactory:
    """The simulator's source for ``--source sim[:SCENARIO]``, paced as its caller asks (the live twin: always)."""

    def make(scenario: str, *, realtime: bool) -> FrameSource:
        if scenario.split(":")[0] == "twin":  # the live twin: a lab with the rovers' firmware, seen by its camera(s)
            from edge.sim.twin.source import twin_source

            return twin_source(config, scenario)
        from edge.sim.source import SimSource

        if scenario.startswith("wide"):  # one camera of the wide arena (a board of several)
            from edge.sim.wide_source import WideCameraSource

            return WideCameraSource(scenario, realtime=realtime)
        return SimSource(scenario or "lab", seed=0, realtime=realtime)

    return make


def grab_configured_frame(config: EdgeConfig) -> NDArray[np.uint8]:
    """One frame of the configured source (its size and controls; the simulator not paced), as a BGR image."""
    from edge.sources import grab_frame

    return grab_frame(camera_source(config.camera, default_sim_factory(config), realtime=False))


def default_tracker_factory(inputs: TrackerInputs) -> Tracker:
    """The pipeline of the rovers, the ``[tracker]`` settings (``auto`` decided by the source), the calibration."""
    from edge.tracker_config import TrackerConfig
    from edge.trackers.factory import build_tracker

    info, settings = inputs.info, inputs.config.tracker
    config = TrackerConfig.of(settings, inputs.config.rovers).for_source(info.chroma_spread, info.sharpened)
    return build_tracker(config, inputs.calibration)


@dataclass
class Appliance:
    """Everything ``edge-ips start`` runs, assembled and checked; :meth:`run` until ``stop`` is set."""

    runtime: EdgeRuntime
    target: BrokerTarget
    broker: EmbeddedBroker | None = None  # started for this appliance
    http: HttpServer | None = None
    dashboard: Dashboard | None = None

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


# -- the steps, in the order prepare_appliance takes them --------------------------------------------------------
def open_source(config: EdgeConfig, sim_factory: SimFactory) -> tuple[FrameSource, SourceInfo]:
    """The configured source, opened (a missing camera is said here, before any port is bound)."""
    source = camera_source(config.camera, sim_factory)
    info = source.open()
    log.info("source: %s", info.description)
    return source, info


def with_sim_rovers(config: EdgeConfig, source: FrameSource) -> EdgeConfig:
    """With the simulated camera and no rovers configured, track the simulator's rovers in its colours."""
    from edge.tracker_config import DEFAULT_ROVERS

    simulated = parse_source(config.camera.source).kind == "sim"
    if not simulated or not isinstance(source, SimulatedScene) or config.rovers != list(DEFAULT_ROVERS):
        return config
    rovers = list(source.rover_configs())
    log.info("rovers: the simulator's, %s", ", ".join(f"{r.id} {r.color_bgr}" for r in rovers))
    return config.model_copy(update={"rovers": rovers})


def calibration_path(config: EdgeConfig, where: str) -> Path | None:
    """The calibration file a real source needs (None for the simulator, which brings its own exact one);
    :class:`CalibrationError` when none is configured or it is not there."""
    if parse_source(config.camera.source).kind == "sim":
        return None
    path = config.calibration.path
    if path is None:
        raise CalibrationError(
            f"no calibration configured: set calibration.path in {where} (make one with `edge-ips calibrate`), "
            "or use --source sim"
        )
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found (calibration.path in {where})")
    return path


def check_calibration(config: EdgeConfig, where: str) -> None:
    """The configured calibration file read and validated, all but its image size (that needs the opened camera):
    ``edge-ips start`` checks it before it makes anything (the dashboard's token), so a bad file stops it first.
    None configured is said after the camera is opened, as a missing camera is the first thing to fix."""
    if config.calibration.path is None:
        return
    path = calibration_path(config, where)
    if path is not None:
        from edge.calibration import load_calibration

        load_calibration(path)


def load_calibration_for(config: EdgeConfig, source: FrameSource, info: SourceInfo, where: str) -> Calibration:
    """The calibration for a real source (required), or the simulator's own exact one."""
    path = calibration_path(config, where)
    if path is None:
        if not isinstance(source, SimulatedScene):
            raise CalibrationError("the simulated camera does not expose its camera model")
        return source.exact_calibration()
    from edge.calibration import load_calibration

    return load_calibration(path, expected_size=(info.width_px, info.height_px))


def start_http(config: EdgeConfig) -> HttpServer | None:
    """The HTTP server of the dashboard, ``/healthz`` and ``/metrics``, bound and serving (None when off)."""
    from edge.httpserver import HttpServer

    if not config.http.enabled:
        return None
    return HttpServer.from_config(config.http, config.dashboard).start()


def start_broker(config: EdgeConfig) -> SelectedBroker:
    """The configured broker, or the embedded one started with the state directory's logins."""
    return select_broker(config, start=True)


def start_recorder(config: EdgeConfig) -> Recorder | None:
    """The recording of everything published (None when ``recording.dir`` is not set)."""
    from edge.recording import Recorder

    if config.recording.dir is None:
        return None
    recorder = Recorder(
        config.recording.dir, max_bytes=config.recording.max_bytes, max_files=config.recording.max_files
    ).start()
    log.info("recording everything published to %s", config.recording.dir)
    return recorder


class _OnConnected:
    """The publisher's (re)connection: a retained stop (at start, and after a broker restart) that releases the
    connection's poses once acknowledged, and a fresh status once the runtime runs."""

    def __init__(self, stop_at_start: StopAtStart) -> None:
        self.stop_at_start = stop_at_start
        self.runtime: EdgeRuntime | None = None

    def __call__(self, hold: ConnectionHold) -> None:
        self.stop_at_start.on_connected(hold)
        if self.runtime is not None:
            self.runtime.status_now()


def start_publisher(
    config: EdgeConfig, target: BrokerTarget, tls: TlsFiles, recorder: Recorder | None, connect_timeout_s: float
) -> tuple[MqttPublisher, _OnConnected]:
    """The edge's MQTT publisher, started; on each connection a retained stop, so that after a restart (the
    edge's or the broker's) every rover halts until commanded again, with the poses held until it is acknowledged.
    Waits up to ``connect_timeout_s`` for both (the broker may come later:
    the publisher keeps trying in the background)."""
    from edge.commands import StopAtStart

    tap = recorder.record if recorder is not None else None
    poses = config.edge.publish == "poses"  # a board of several publishes detections, and no formation
    stop_at_start = StopAtStart(target, client_id=f"edge-ips-{config.edge.id}-stop", tls=tls, tap=tap, retry=poses)
    on_connected = _OnConnected(stop_at_start)
    publisher = MqttPublisher(
        target,
        edge_id=config.edge.id,
        # a board of several calls nobody missing, in its last will too (the fuser knows who nobody sees)
        rovers=[r.id for r in config.rovers] if poses else [],
        client_id=config.broker.client_id,
        keepalive_s=config.broker.keepalive_s,
        reconnect_min_s=config.broker.reconnect_min_s,
        reconnect_max_s=config.broker.reconnect_max_s,
        tls=tls,
        tap=tap,
        on_connected=on_connected,
        hold_poses=poses,  # no pose on a connection before its stop is acknowledged (StopAtStart)
    )
    publisher.start()
    if not publisher.wait_connected(connect_timeout_s):
        log.warning("broker %s not reachable yet; retrying in the background", target.display())
    elif not stop_at_start.done.wait(connect_timeout_s):  # before any command can be taken (dashboard)
        log.warning("the retained stop at start is not acknowledged yet%s", ": poses stay held until it is" * poses)
    return publisher, on_connected


def start_dashboard_for(
    config: EdgeConfig,
    runtime: EdgeRuntime,
    http: HttpServer,
    calibration: Any,
    target: BrokerTarget,
    tls: TlsFiles,
) -> Dashboard | None:
    """The live page on the HTTP server (None when ``dashboard.enabled`` is off)."""
    if not config.dashboard.enabled:
        return None
    from edge.dashboard import start_dashboard

    dashboard = start_dashboard(config, runtime, http, calibration=calibration, target=target, tls=tls)
    log.info("dashboard on http://%s:%d/", _display_host(http.host), http.port)
    return dashboard


def add_sim_panel(
    config: EdgeConfig,
    http: HttpServer,
    source: FrameSource,
    broker: SelectedBroker,
    restart_argv: Sequence[str] | None,
) -> None:
    """The simulator panel's routes (scatter, faults) when the source is a lab that offers them (``sim:twin``)."""
    from edge.dashboard.sim_panel import attach_sim_panel

    enabled = config.dashboard.token is not None
    attach_sim_panel(http, source, broker=broker.started, restart_argv=restart_argv, enabled=enabled)


def add_health_routes(http: HttpServer, runtime: EdgeRuntime, recorder: Recorder | None) -> None:
    """``/healthz`` and ``/metrics``: last, so that once ``/healthz`` answers every route is there."""
    from edge.httpserver import Response
    from edge.metrics import exposition, metrics_registry

    registry = metrics_registry(runtime.snapshot, http=http, recorder=recorder)
    http.route("/healthz", health_route(runtime))
    http.route("/metrics", lambda request: Response(200, *exposition(registry)))


def health_route(runtime: EdgeRuntime) -> Handler:
    """``/healthz``, answered on the HTTP server's loop (a snapshot is quick): no worker thread needed."""
    from edge.httpserver import Request, Response

    async def health(request: Request) -> Response:
        snap = runtime.snapshot()
        body = json.dumps(snap.health()).encode() + b"\n"
        return Response(200 if snap.state == "online" else 503, body, "application/json")

    return health


def _display_host(host: str) -> str:
    return "localhost" if host in ("0.0.0.0", "::", "") else host


# -- the whole ---------------------------------------------------------------------------------------------------
def prepare_appliance(
    config: EdgeConfig,
    *,
    config_where: str = "the configuration",
    tracker_factory: TrackerFactory = default_tracker_factory,
    sim_factory: SimFactory | None = None,
    calibration_loader: CalibrationLoader | None = None,
    connect_timeout_s: float = 3.0,
    restart_argv: Sequence[str] | None = None,
) -> Appliance:
    """Open the source, load the calibration, build the tracker, bind the ports, start the broker, connect.

    Every user-fixable problem raises an :class:`EdgeIpsError` here, before any frame is published; whatever was
    already started is stopped again. ``restart_argv``: how this process was started (``edge-ips start``), for a
    simulated lab's "edge killed" fault.
    """
    cam = config.camera
    tls = TlsFiles.of(config.broker)
    if broker_target(config.broker).tls:
        tls.check()
    with contextlib.ExitStack() as started:
        # The source, its calibration and the tracker first: a missing camera or a bad calibration is said before
        # any port is bound (and not hidden behind a port that is taken).
        source, info = open_source(config, sim_factory or default_sim_factory(config))
        started.callback(source.close)
        config = with_sim_rovers(config, source)
        calibration = (calibration_loader or load_calibration_for)(config, source, info, config_where)
        tracker = tracker_factory(TrackerInputs(config, source, info, calibration))

        http = start_http(config)
        if http is not None:
            started.callback(http.stop)
        broker = start_broker(config)
        started.callback(broker.stop)
        recorder = start_recorder(config)
        if recorder is not None:
            started.callback(recorder.close)
        publisher, on_connected = start_publisher(config, broker.target, tls, recorder, connect_timeout_s)
        started.callback(publisher.stop)

        runtime = EdgeRuntime(
            edge_id=config.edge.id,
            source=source,
            info=info,
            tracker=tracker,
            publisher=publisher,
            rovers=[r.id for r in config.rovers],
            broker_display=broker.target.display(),
            status_interval_s=config.edge.status_interval_s,
            stall_timeout_s=cam.stall_timeout_s,
            reopen_min_s=cam.reopen_min_s,
            reopen_max_s=cam.reopen_max_s,
            recorder=recorder,
            detections=detection_builder_for(config, calibration, info, parse_source(cam.source).kind == "sim"),
        )
        on_connected.runtime = runtime
        dashboard = None
        if http is not None:
            dashboard = start_dashboard_for(config, runtime, http, calibration, broker.target, tls)
            if dashboard is not None:
                started.callback(dashboard.close)
                add_sim_panel(config, http, source, broker, restart_argv)
            add_health_routes(http, runtime, recorder)
        started.pop_all()  # all checks passed: the appliance owns what was started
    return Appliance(runtime=runtime, target=broker.target, broker=broker.started, http=http, dashboard=dashboard)


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


def why_this_source(loaded: LoadedConfig, *, source_given: bool) -> str:
    """Why the appliance runs the source it runs, for the first log line."""
    if source_given:
        return "from --source"
    if loaded.path is not None:
        return f"camera.source in {loaded.where}"
    import glob

    cameras = sorted(glob.glob("/dev/video*"))
    runs = "the live twin" if loaded.config.camera.source == "sim:twin" else "the simulated camera"
    return f"no configuration found, so {runs}; " + (
        f"a camera is attached at {cameras[0]}: calibrate it (edge-ips calibrate) and use --source {cameras[0]}"
        if cameras
        else "no camera is attached: plug one in and use --source /dev/video0"
    )


def start(loaded: LoadedConfig, *, source_given: bool = False, restart_argv: Sequence[str] | None = None) -> None:
    """``edge-ips start``: log what runs (edge, source and why, broker, configuration), assemble the appliance and
    run it until SIGTERM or SIGINT (``restart_argv``: see :func:`prepare_appliance`)."""
    from edge.broker.clients import broker_summary

    config = loaded.config
    log.info(
        "edge-ips start: edge %s, source %s (%s), broker %s, configuration: %s",
        config.edge.id,
        config.camera.source,
        why_this_source(loaded, source_given=source_given),
        broker_summary(config),
        loaded.where,
    )
    if loaded.env_keys:
        log.info("environment overrides: %s", ", ".join(loaded.env_keys))
    run_until_signalled(prepare_appliance(config, config_where=loaded.where, restart_argv=restart_argv))
