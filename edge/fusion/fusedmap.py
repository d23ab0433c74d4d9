"""The fused map on a page (``edge-ips fuse --broker URL --http-port P``): every board's view on the floor, every
rover's fused position, which boards measured it, and each board's camera image (its own dashboard's
``/api/frame.jpg``, fetched by the browser from the board: ``--board-dashboard EDGE=URL``).

:func:`map_state` is a pure function of the fuser's status and its newest fused poses; :func:`serve_map` puts it
and the page (``edge/fusion/static/map.html``) on an :class:`edge.httpserver.HttpServer`: ``/`` (open, like the
dashboard's page) and ``/api/fusion`` (``read``: the dashboard's viewer token when one is configured).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import resources
from typing import TYPE_CHECKING, Any

from edge.board_messages import FuserStatusV1
from edge.fusion.core import FusedPose

if TYPE_CHECKING:
    from edge.httpserver import HttpServer, Request, Response


def map_state(
    status: FuserStatusV1,
    poses: Mapping[str, FusedPose],
    now_s: float,
    timeout_s: float,
    dashboards: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """What the page draws: the boards (state, view polygon in floor cm, clock offset, the rovers in their latest
    detections, the address of their dashboard where it was given: the page shows its camera image), each rover
    fused within ``timeout_s`` (position, heading, the boards that measured it, age), the rovers missing, and the
    views of the boards that are down (where nobody looks)."""
    dashboards = dashboards or {}
    boards = [
        {
            "edge": b.edge,
            "state": b.state,
            "view": b.view,
            "offset_ms": b.offset_ms,
            "rovers": b.rovers,
            "dashboard": dashboards.get(b.edge),
        }
        for b in status.boards
    ]
    rovers = []
    for rover_id in sorted(poses):
        pose = poses[rover_id]
        age_s = now_s - pose.t_s
        if age_s > timeout_s:
            continue
        rovers.append(
            {
                "id": rover_id,
                "x": round(pose.x_cm, 2),
                "y": round(pose.y_cm, 2),
                "theta": None if pose.theta_rad is None else round(pose.theta_rad, 4),
                "q": round(pose.quality, 2),
                "boards": list(pose.boards),
                "age_ms": round(1e3 * max(age_s, 0.0), 1),
            }
        )
    return {
        "fuser": status.fuser,
        "state": status.state,
        "holder": status.holder,
        "boards": boards,
        "rovers": rovers,
        "missing": status.missing,
        "unwatched": [b.view for b in status.boards if b.state != "ok" and b.view],
        "t": status.t,
    }


def map_page() -> bytes:
    """The page, read from the installed package."""
    return (resources.files("edge.fusion") / "static" / "map.html").read_bytes()


def serve_map(http: HttpServer, state: Callable[[], dict[str, Any]]) -> None:
    """``/``: the page; ``/api/fusion``: ``state()`` as JSON, asked afresh on every request."""
    from edge.httpserver import Response, json_response

    page = Response(200, map_page(), "text/html; charset=utf-8")

    async def index(request: Request) -> Response:
        return page

    def fusion(request: Request) -> Response:
        return json_response(200, state())

    http.route("/", index)
    http.route("/api/fusion", fusion, access="read")
