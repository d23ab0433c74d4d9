"""The dashboard's HTTP side, on the appliance's own server (``edge.httpserver``, port 8080).

Routes (access levels of :mod:`edge.httpguard`):

- ``GET /`` and ``GET /static/<file>`` (open): the page (``edge/dashboard/static``, no build step); it holds no
  data, and asks for the token when the API answers 401.
- ``GET /api/state`` (read): what does not change while running (edge id, working area in cm and in image pixels,
  image size, rovers and their colours, whether the formation controls are enabled, the calibration's figures)
  and the current formation.
- ``GET /api/events`` (read): server-sent events ``pose`` (capped at ``dashboard.pose_hz``), ``status`` (1 Hz),
  ``formation`` and ``rovers`` (when they change), from :class:`edge.dashboard.events.EventHub` through
  :class:`edge.dashboard.streams.EventFanout`.
- ``GET /api/rovers`` (read): what each rover reports it applies (its retained status: halt reason, formation kind
  and seq) and whether that is the broker's retained formation (:func:`edge.dashboard.events.rovers_event`).
- ``GET /api/frame.jpg`` (read): the next camera frame as JPEG (:class:`edge.dashboard.frames.FrameEncoder`).
- ``GET /api/errormap.png`` (read): the calibration error map (:mod:`edge.dashboard.calibration_view`).
- ``POST /api/formation`` (control): ``Authorization: Bearer <dashboard.token>``, JSON ``{kind, ids, spacing,
  side}``; publishes the retained formation (:mod:`edge.dashboard.formation`).
- ``POST /api/stop`` (stop): the page's STOP, a retained ``stop`` as ``/api/formation`` would publish it (no body);
  with the right token it goes through even from an address locked out for wrong tokens (:mod:`edge.httpguard`).
- ``/api/enroll`` and ``/api/enroll/...``: colour enrolment of the rovers in view (:mod:`edge.dashboard.enrolment`).

Everything reads the runtime's snapshots and newest-result reference; nothing here takes a lock the tracker holds
for longer than a counter update.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Sequence
from importlib import resources
from typing import TYPE_CHECKING, Any

from edge.dashboard.streams import EventFanout
from edge.httpserver import HttpServer, Request, Response, json_response

STOP_BODY = b'{"kind": "stop", "ids": []}'  # what the page posted to /api/formation for its STOP

if TYPE_CHECKING:
    from edge.config import DashboardSection
    from edge.dashboard.calibration_view import CalibrationView
    from edge.dashboard.events import EventHub, Overlay
    from edge.dashboard.formation import FormationDesk
    from edge.dashboard.frames import FrameEncoder
    from edge.dashboard.runtime_view import RuntimeView
    from edge.tracker_config import RoverConfig

log = logging.getLogger("edge.dashboard")

CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".png": "image/png",
    ".svg": "image/svg+xml",
    ".ico": "image/x-icon",
}


def hex_color(color_bgr: Sequence[int]) -> str:
    """(B, G, R) 0-255 -> ``#rrggbb``."""
    b, g, r = (max(0, min(255, int(c))) for c in color_bgr)
    return f"#{r:02x}{g:02x}{b:02x}"


def static_files() -> dict[str, tuple[bytes, str]]:
    """``{file name: (bytes, content type)}`` of the page, read from the installed package."""
    folder = resources.files("edge.dashboard") / "static"
    out: dict[str, tuple[bytes, str]] = {}
    for item in folder.iterdir():
        suffix = "." + item.name.rsplit(".", 1)[-1] if "." in item.name else ""
        if item.is_file() and suffix in CONTENT_TYPES:
            out[item.name] = (item.read_bytes(), CONTENT_TYPES[suffix])
    return out


def _fixed(response: Response) -> Callable[[Request], Awaitable[Response]]:
    async def serve(request: Request) -> Response:
        return response

    return serve


class Dashboard:
    """The page's routes over one running runtime (:class:`RuntimeView`); :meth:`attach` registers them, :meth:`close`
    ends the event streams, the encoder and the formation watcher."""

    def __init__(
        self,
        runtime: RuntimeView,
        *,
        settings: DashboardSection,
        rovers: Sequence[RoverConfig],
        area_cm: tuple[float, float, float, float],
        overlay: Overlay,
        calibration: CalibrationView,
        hub: EventHub,
        encoder: FrameEncoder,
        formation: FormationDesk | None,
    ) -> None:
        self.runtime = runtime
        self.settings = settings
        self.rovers = tuple(rovers)
        self.area_cm = area_cm
        self.overlay = overlay
        self.calibration = calibration
        self.hub = hub
        self.encoder = encoder
        self.formation = formation
        self._static = static_files()
        self._area_px = overlay.area_px()
        self.fanout = EventFanout(hub.stream)

    # -- routes -----------------------------------------------------------------------------------------------
    def attach(self, http: HttpServer) -> Dashboard:
        index = self._static.get("index.html")
        if index is None:
            raise FileNotFoundError("edge/dashboard/static/index.html is missing from the installed package")
        http.route("/", _fixed(Response(200, index[0], index[1])))
        for name, (body, content_type) in self._static.items():
            http.route(f"/static/{name}", _fixed(Response(200, body, content_type)))
        http.route("/api/state", self.state, access="read")
        http.route("/api/events", self.events, access="read")
        http.route("/api/frame.jpg", self.frame, access="read")
        http.route("/api/errormap.png", self.errormap, access="read")
        http.route("/api/formation", self.post_formation, method="POST", access="control")
        http.route("/api/stop", self.post_stop, method="POST", access="stop")
        http.route("/api/rovers", self.rover_reports, access="read")
        return self

    def state(self, request: Request) -> Response:
        x0, y0, x1, y1 = self.area_cm
        info = self.runtime.info
        return json_response(
            200,
            {
                "edge_id": self.runtime.edge_id,
                "area": {"x0_cm": x0, "y0_cm": y0, "width_cm": x1 - x0, "length_cm": y1 - y0},
                "area_px": self._area_px,
                "image": {"width": info.width_px, "height": info.height_px},
                "rovers": [{"id": r.id, "color": hex_color(r.color_bgr)} for r in self.rovers],
                "formation_enabled": self.formation is not None and self.formation.enabled,
                "formation": None if self.formation is None else self.formation.current,
                "calibration": self.calibration.summary(),
                "frame": {"max_fps": self.settings.frame_fps, "max_width_px": self.settings.max_width_px},
                "pose_hz": self.settings.pose_hz,
            },
        )

    async def events(self, request: Request) -> Response:
        from edge.dashboard.events import sse, status_event

        first: list[tuple[str, Any]] = [("status", status_event(self.runtime.snapshot()))]
        if self.formation is not None:
            first.append(("formation", self.formation.current))
            first.append(("rovers", self._reports(self.formation)))
        opening = b"retry: 2000\n\n" + b"".join(sse(name, data) for name, data in first)
        return Response(
            200,
            content_type="text/event-stream; charset=utf-8",
            headers={"X-Accel-Buffering": "no"},
            stream=self.fanout.stream(opening),
        )

    def _reports(self, desk: FormationDesk) -> dict[str, Any]:
        from edge.dashboard.events import rovers_event

        return rovers_event([r.id for r in self.rovers], desk.reports, desk.current)

    def rover_reports(self, request: Request) -> Response:
        if self.formation is None:
            return json_response(404, {"error": "rover statuses are not watched on this edge"})
        return json_response(200, self._reports(self.formation))

    async def frame(self, request: Request) -> Response:
        encoded = await self.encoder.wait_frame()
        if encoded is None:
            return json_response(503, {"error": "no camera frame yet"})
        return Response(
            200,
            encoded.jpeg,
            "image/jpeg",
            headers={"X-Frame-Index": str(encoded.index), "X-Frame-Seq": str(encoded.seq)},
        )

    def errormap(self, request: Request) -> Response:
        return Response(200, self.calibration.png(), "image/png")

    def post_formation(self, request: Request, posted: bytes | None = None) -> Response:
        if self.formation is None:
            return json_response(403, {"error": "formation controls are not available on this edge"})
        status, body = self.formation.command(request.headers, request.body if posted is None else posted)
        response = json_response(status, body)
        if status == 401:
            response.headers["WWW-Authenticate"] = 'Bearer realm="edge-ips dashboard"'
        return response

    def post_stop(self, request: Request) -> Response:
        return self.post_formation(request, STOP_BODY)

    def close(self) -> None:
        self.hub.close()
        self.encoder.close()
        if self.formation is not None:
            self.formation.close()
