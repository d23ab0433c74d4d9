"""The live web dashboard served by ``edge-ips start``: camera view with overlays, top-down map, rover
status, calibration error map, formation controls, colour enrolment of the rovers in view.

The parts: ``server`` (routes on the appliance's HTTP server), ``events`` (server-sent events built from
snapshots), ``frames`` (the JPEG camera view, on its own thread), ``formation`` (token-checked commands and the
retained formation), ``calibration_view`` (the error map panel), ``enrolment`` (the rovers' colours measured from
the camera). The page itself is ``static/`` (no build step).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from edge.dashboard.server import Dashboard

if TYPE_CHECKING:
    from edge.config import BrokerTarget, EdgeConfig
    from edge.dashboard.runtime_view import RuntimeView
    from edge.httpserver import HttpServer
    from edge.mqttclient import TlsFiles

__all__ = ["Dashboard", "start_dashboard"]


def start_dashboard(
    config: EdgeConfig,
    runtime: RuntimeView,
    http: HttpServer,
    *,
    calibration: Any,
    target: BrokerTarget,
    tls: TlsFiles | None = None,
) -> Dashboard:
    """Build the dashboard for a prepared runtime (an :class:`edge.runtime.EdgeRuntime`) and register its routes on
    ``http``.

    ``calibration``: the tracker's :class:`edge.calibration.Calibration` (None when unknown: no overlays).
    ``target``: the broker the formation commands go to (the appliance's own, embedded port resolved).
    """
    from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
    from edge.dashboard.calibration_view import CalibrationView
    from edge.dashboard.enrolment import EnrolDesk
    from edge.dashboard.events import EventHub, Overlay, pose_event, rovers_event, status_event
    from edge.dashboard.formation import FormationDesk, with_targets
    from edge.dashboard.frames import FrameEncoder
    from edge.source_spec import parse_source

    settings = config.dashboard
    overlay = Overlay(calibration, config.tracker.marker_length_cm, config.tracker.marker_width_cm)
    rover_ids = [r.id for r in config.rovers]
    area_cm = calibration.area_cm if calibration is not None else (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM)

    def background() -> Any:
        frame = runtime.newest_frame()
        return None if frame is None else frame.image

    view = CalibrationView(
        calibration,
        simulated=parse_source(config.camera.source).kind == "sim",
        path=config.calibration.path,
        background=background,
    )
    hub = EventHub(
        latest=lambda: runtime.latest_result,
        make_pose=lambda result: with_targets(pose_event(result, overlay, rover_ids), desk.current),
        make_status=lambda: status_event(runtime.snapshot()),
        pose_hz=settings.pose_hz,
        wait_next=runtime.wait_tracked,
    )
    encoder = FrameEncoder(
        lambda: runtime.last_frame,  # the frame just tracked: encoded in the gap before the next one arrives
        max_fps=settings.frame_fps,
        quality=settings.jpeg_quality,
        max_width_px=settings.max_width_px,
        wait_next=runtime.wait_tracked,
    )
    token = settings.token.get_secret_value() if settings.token is not None else None

    def reported() -> dict[str, Any]:
        return rovers_event(rover_ids, desk.reports, desk.current)

    def on_change(formation: dict[str, Any] | None) -> None:
        hub.publish("formation", formation)
        hub.publish("rovers", reported())  # whether each rover is on the retained command may have changed

    desk = FormationDesk(
        target,
        edge_id=config.edge.id,
        rover_ids=rover_ids,
        token=token,
        tls=tls,
        on_change=on_change,
        on_report=lambda rover_id, report: hub.publish("rovers", reported()),
    )
    desk.start()  # after the assignment: the retained formation may arrive (and call on_change) at once
    dashboard = Dashboard(
        runtime,
        settings=settings,
        rovers=config.rovers,
        area_cm=area_cm,
        overlay=overlay,
        calibration=view,
        hub=hub,
        encoder=encoder,
        formation=desk,
    )
    dashboard.attach(http)
    EnrolDesk(
        runtime,
        calibration,
        enabled=token is not None,
        marker_length_cm=config.tracker.marker_length_cm,
        marker_width_cm=config.tracker.marker_width_cm,
        rovers_file=settings.rovers_file,
        source=runtime.info.description,
    ).attach(http)
    return dashboard
