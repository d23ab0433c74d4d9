"""The dashboard's HTTP side, on the appliance's own server (``edge.httpserver``, port 8080).

Routes:

- ``GET /`` and ``GET /static/<file>``: the page (``edge/dashboard/static``, no build step).
- ``GET /api/state``: what does not change while running (edge id, working area in cm and in image pixels, image
  size, rovers and their colours, whether the formation controls are enabled, the calibration's figures) and the
  current formation.
- ``GET /api/events``: server-sent events ``pose`` (capped at ``dashboard.pose_hz``), ``status`` (1 Hz) and
  ``formation`` (when it changes), from :class:`edge.dashboard.events.EventHub`.
- ``GET /api/frame.jpg``: the next camera frame as JPEG (:class:`edge.dashboard.frames.FrameEncoder`).
- ``GET /api/errormap.png``: the calibration error map (:mod:`edge.dashboard.calibration_view`).
- ``POST /api/formation``: ``Authorization: Bearer <dashboard.token>``, JSON ``{kind, ids, spacing, side}``;
  publishes the retained formation (:mod:`edge.dashboard.formation`).

Everything reads the runtime's snapshots and newest-result reference; nothing here takes a lock the tracker holds
for longer than a counter update.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from importlib import resources
from typing import TYPE_CHECKING, Any

from edge.dashboard.threads import background_priority
from edge.httpserver import HttpServer, Request, Response

if TYPE_CHECKING:
    from edge.config import DashboardSection
    from edge.dashboard.calibration_view import CalibrationView
    from edge.dashboard.events import EventHub, Overlay
    from edge.dashboard.formation import FormationDesk
    from edge.dashboard.frames import FrameEncoder
    from edge.runtime import EdgeRuntime
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


def json_response(status: int, data: Any) -> Response:
    body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode()
    return Response(status, body, "application/json")


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


def _fixed(response: Response) -> Callable[[Request], Response]:
    return lambda request: response


class Dashboard:
    """The page's routes over one running :class:`EdgeRuntime`; :meth:`attach` registers them, :meth:`close`
    ends the event streams, the encoder and the formation watcher."""

    def __init__(
        self,
        runtime: EdgeRuntime,
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

    # -- routes -----------------------------------------------------------------------------------------------
    def attach(self, http: HttpServer) -> Dashboard:
        index = self._static.get("index.html")
        if index is None:
            raise FileNotFoundError("edge/dashboard/static/index.html is missing from the installed package")
        http.route("/", lambda request: Response(200, index[0], index[1]))
        for name, (body, content_type) in self._static.items():
            http.route(f"/static/{name}", _fixed(Response(200, body, content_type)))
        http.route("/api/state", self.state)
        http.route("/api/events", self.events)
        http.route("/api/frame.jpg", self.frame)
        http.route("/api/errormap.png", self.errormap)
        http.route("/api/formation", self.post_formation, method="POST")
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

    def events(self, request: Request) -> Response:
        from edge.dashboard.events import status_event

        first: list[tuple[str, Any]] = [("status", status_event(self.runtime.snapshot()))]
        if self.formation is not None:
            first.append(("formation", self.formation.current))
        return Response(
            200,
            content_type="text/event-stream; charset=utf-8",
            headers={"X-Accel-Buffering": "no"},
            stream=self.hub.stream(first),
        )

    def frame(self, request: Request) -> Response:
        background_priority()  # the request's thread only serves the page
        encoded = self.encoder.next_frame()
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

    def post_formation(self, request: Request) -> Response:
        if self.formation is None:
            return json_response(403, {"error": "formation controls are not available on this edge"})
        status, body = self.formation.command(request.headers, request.body)
        response = json_response(status, body)
        if status == 401:
            response.headers["WWW-Authenticate"] = 'Bearer realm="edge-ips dashboard"'
        return response

    def close(self) -> None:
        self.hub.close()
        self.encoder.close()
        if self.formation is not None:
            self.formation.close()
