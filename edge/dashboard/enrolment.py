"""The dashboard's colour enrolment: "enroll the rovers now in view", as ``edge-ips rovers enroll`` does from files.

A lab does it in three steps on the page: clear the floor and capture it, place the rovers, enroll. The
measurement is :func:`edge.enroll.enroll` on the runtime's newest tracked frame, with the calibration and marker
size the appliance tracks with, against one of two empty scenes:

- **the captured floor** (``POST /api/enroll/floor``): the newest frame when the user said the floor is empty. It is
  kept until forgotten (``DELETE``) or the appliance restarts. Capturing warns, and does not refuse, when the
  tracker sees a rover in that frame (the starter colours of a new lab may match anything or nothing);
- **the tracker's own background model**, used when no floor was captured. It shows the empty floor only under the
  rovers the tracker tracks (it learns anything else into the floor within ``[tracker] background_refresh_s``, a
  new rover parked in view included), and only where it has seen the floor bare: so it re-enrolls the fleet the
  appliance tracks (after new lamps or another white balance) without clearing the floor, and is refused until it
  has seen all but ``MIN_KNOWN_SHARE`` of the image without a tracked rover on it.

The answer lists each marker (proposed id, colour, size, two-tone front, the tracked rover standing on it), the
warnings (hues too close to tell apart, odd sizes, a floor near a marker's hue) and the ``[[rovers]]`` TOML, which
the page offers to download.
``POST /api/enroll/save`` writes the last enrolment (never text from the request) to ``dashboard.rovers_file``
when that is configured: an existing file is replaced only when the request says so (the page asks first), and a
configuration with other sections never (:func:`edge.enroll.save_enrolment`). The appliance keeps tracking with the
rovers it started with: the file takes effect at the next start.

Control routes answer 403 when no dashboard token is configured (the HTTP guard checks the token when one is).
"""

from __future__ import annotations

import json
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from edge.dashboard.frames import encode_jpeg
from edge.dashboard.server import hex_color
from edge.enroll import EnrolledMarker, Enrolment, enroll, save_enrolment
from edge.errors import EnrollmentError, describe_validation
from edge.floor_change import in_background
from edge.httpserver import Request, Response, json_response

if TYPE_CHECKING:
    from edge.background import BackgroundModel
    from edge.httpserver import HttpServer
    from edge.metrics import Snapshot
    from edge.trackers.base import PlaneMapping
    from edge.tracking import Frame, FrameResult

log = logging.getLogger("edge.dashboard")

MIN_KNOWN_SHARE = 0.999  # of the image the tracker's model must have seen bare (a parked rover is ~0.3 % of it)
TRACKED_WITHIN_CM = 15.0  # a tracked rover this close to an enrolled marker's centre is standing on it
MAX_BODY_BYTES = 4096
RECENT_S = 1.0  # a rover the tracker saw this recently is taken to be on the floor still (capturing it)


class LiveCamera(Protocol):
    """What enrolment reads from the running appliance (:class:`edge.runtime.EdgeRuntime` has it)."""

    @property
    def last_frame(self) -> Frame | None: ...

    @property
    def latest_result(self) -> FrameResult | None: ...

    @property
    def tracker(self) -> object: ...

    def camera_state(self) -> str: ...

    def wait_tracked(self, timeout_s: float) -> None: ...

    def snapshot(self) -> Snapshot: ...


class EnrolRequest(BaseModel):
    """``POST /api/enroll``. ``ids``: one per marker (hue names go to the nearest hue, others in order of x then y),
    or none: named by hue. ``background``: ``auto`` (the captured floor, else the tracker's model)."""

    model_config = ConfigDict(extra="forbid")

    ids: list[str] | None = Field(default=None, max_length=32)
    background: Literal["auto", "floor", "tracker"] = "auto"


class SaveRequest(BaseModel):
    """``POST /api/enroll/save``: which enrolment (its number), and whether an existing file may be replaced."""

    model_config = ConfigDict(extra="forbid")

    enrolment: int
    replace: bool = False


@dataclass(frozen=True)
class Floor:
    """An empty scene to enroll against: the captured frame, or the tracker's model at the time of asking."""

    image: NDArray[np.uint8]
    kind: Literal["floor", "tracker"]
    frame_index: int | None = None
    t_capture_s: float | None = None

    def describe(self) -> dict[str, Any]:
        h, w = self.image.shape[:2]
        return {"kind": self.kind, "frame": self.frame_index, "t": self.t_capture_s, "width": w, "height": h}


@dataclass(frozen=True)
class _Done:
    number: int
    enrolment: Enrolment
    toml: str


class Refused(Exception):
    """A request that cannot be served: its HTTP status, the one-line reason the page shows, and what else the page
    needs to know (``{"exists": True}``: the file is there, ask before replacing it)."""

    def __init__(self, status: int, error: str, **extra: Any) -> None:
        super().__init__(error)
        self.status = status
        self.error = error
        self.extra = extra


# -- the pure part -------------------------------------------------------------------------------------------------
def parse_body(body: bytes, model: type[BaseModel], what: str) -> Any:
    """A validated request model; raises :class:`Refused` (400) naming the field at fault."""
    if len(body) > MAX_BODY_BYTES:
        raise Refused(400, f"{what}: body of {len(body)} bytes exceeds {MAX_BODY_BYTES}")
    try:
        data = json.loads(body) if body.strip() else {}
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Refused(400, f"{what}: not JSON ({exc})") from None
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise Refused(400, f"{what}: {describe_validation(exc, top_level='(body)')}") from None


@runtime_checkable
class KeepsBackground(Protocol):
    """A tracker that keeps a background model (optional: check with ``isinstance``): the default pipeline does
    (None until its first frame); the paper's full-frame pipeline keeps colour planes, not a frame."""

    background: BackgroundModel | None


def tracker_model(tracker: object) -> BackgroundModel | None:
    """The tracker's background model when it keeps one."""
    return tracker.background if isinstance(tracker, KeepsBackground) else None


def known_share(model: BackgroundModel) -> float:
    """Share of the image where ``model`` has seen the floor with no tracked rover on it."""
    return float(np.count_nonzero(model.valid)) / max(1, model.valid.size)


def tracked_on(marker: EnrolledMarker, result: FrameResult | None) -> str | None:
    """The id of the tracked rover standing on ``marker`` in ``result`` (same frame), if any."""
    if result is None or not result.estimates:
        return None
    x, y = marker.xy_cm
    nearest = min(result.estimates, key=lambda e: math.hypot(e.x_cm - x, e.y_cm - y))
    return nearest.rover_id if math.hypot(nearest.x_cm - x, nearest.y_cm - y) <= TRACKED_WITHIN_CM else None


def _rovers(n: int) -> str:
    return f"{n} rover" if n == 1 else f"{n} rovers"


def marker_json(marker: EnrolledMarker, tracked_as: str | None) -> dict[str, Any]:
    """One enrolled marker for the page: the ``[[rovers]]`` values and what was measured."""
    front = None
    if marker.front_color_bgr is not None:
        front = {
            "color": hex_color(marker.front_color_bgr),
            "color_bgr": list(marker.front_color_bgr),
            "fraction": marker.front_fraction,
        }
    return {
        "id": marker.rover_id,
        "color": hex_color(marker.color_bgr),
        "color_bgr": list(marker.color_bgr),
        "hue_deg": marker.hue_deg,
        "saturation": marker.saturation,
        "spread_deg": marker.spread_deg,
        "x_cm": marker.xy_cm[0],
        "y_cm": marker.xy_cm[1],
        "u_px": marker.uv_px[0],
        "v_px": marker.uv_px[1],
        "length_cm": marker.length_cm,
        "width_cm": marker.width_cm,
        "area_cm2": marker.area_cm2,
        "front": front,
        "tracked_as": tracked_as,
    }


# -- the desk ------------------------------------------------------------------------------------------------------
class EnrolDesk:
    """Holds the captured floor and the last enrolment; serves the ``/api/enroll`` routes (see the module docstring).

    ``calibration``: the tracker's (None: enrolment is unavailable). ``enabled``: a dashboard token is configured.
    ``rovers_file``: where "save" writes (None: download only). ``source``: the camera's description, for the file.
    """

    def __init__(
        self,
        camera: LiveCamera,
        calibration: PlaneMapping | None,
        *,
        enabled: bool,
        marker_length_cm: float,
        marker_width_cm: float,
        rovers_file: Path | None = None,
        source: str = "",
    ) -> None:
        self.camera = camera
        self.calibration = calibration
        self.enabled = enabled
        self.marker_size_cm = (marker_length_cm, marker_width_cm)
        self.rovers_file = rovers_file
        self.source = source
        self._lock = threading.Lock()  # the floor and the last enrolment
        self._busy = threading.Lock()  # one enrolment at a time: each takes a core for a while
        self._floor: Floor | None = None
        self._last: _Done | None = None
        self._count = 0

    def attach(self, http: HttpServer) -> EnrolDesk:
        http.route("/api/enroll", self.status, access="read")
        http.route("/api/enroll", self.post_enroll, method="POST", access="control")
        http.route("/api/enroll/floor", self.capture_floor, method="POST", access="control")
        http.route("/api/enroll/floor", self.forget_floor, method="DELETE", access="control")
        http.route("/api/enroll/floor.jpg", self.floor_jpeg, access="read")
        http.route("/api/enroll/save", self.post_save, method="POST", access="control")
        return self

    # -- state ----------------------------------------------------------------------------------------------------
    def _unavailable(self) -> str | None:
        if not self.enabled:
            return "enrolment is disabled: no dashboard token is configured (dashboard.token)"
        if self.calibration is None:
            return "enrolment needs the calibration, and this edge has none"
        return None

    def state(self) -> dict[str, Any]:
        with self._lock:
            floor = self._floor
        model = tracker_model(self.camera.tracker)
        known = None if model is None else known_share(model)
        path = self.rovers_file
        return {
            "enabled": self._unavailable() is None,
            "reason": self._unavailable(),
            "floor": None if floor is None else floor.describe(),
            # ready: the enrolment's own test (rounded, a share just under the bar read as reaching it)
            "tracker_model": None if known is None else {"known": round(known, 4), "ready": known >= MIN_KNOWN_SHARE},
            "min_known": MIN_KNOWN_SHARE,
            "rovers_file": None if path is None else str(path),
            "rovers_file_exists": path is not None and path.exists(),
        }

    def _newest(self) -> tuple[Frame, FrameResult | None]:
        """The newest tracked frame and the tracker's result for it (None when they cannot be paired)."""
        state = self.camera.camera_state()
        if state != "ok":
            raise Refused(503, f"no current camera frame: the camera is {state}")
        for _ in range(3):
            result, frame = self.camera.latest_result, self.camera.last_frame
            if frame is not None and result is not None and result.frame_index == frame.index:
                return frame, result
            self.camera.wait_tracked(1.0)  # the tracker is between the two: right after its next frame they pair
        if frame is None:
            raise Refused(503, "no camera frame tracked yet")
        return frame, None

    def _background(self, choice: str, frame: Frame) -> Floor:
        with self._lock:
            floor = self._floor
        if choice in ("auto", "floor") and floor is not None:
            return floor
        if choice == "floor":
            raise Refused(400, "no empty floor captured: clear the floor and capture it first")
        model = tracker_model(self.camera.tracker)
        if model is None:
            raise Refused(
                400, "capture the empty floor first (clear the floor, capture it, then place the rovers and enroll)"
            )
        share = known_share(model)
        if share < MIN_KNOWN_SHARE:
            raise Refused(
                400,
                f"the tracker's background model has seen only {100 * share:.1f} % of the image without a tracked "
                "rover on it (a rover that has not moved since the start hides the floor under it): capture the "
                "empty floor first",
            )
        return Floor(model.reference.copy(), "tracker", frame.index, frame.t_capture_s)

    # -- routes ---------------------------------------------------------------------------------------------------
    def status(self, request: Request) -> Response:
        return json_response(200, self.state())

    def _serve(self, work: Callable[[], dict[str, Any]]) -> Response:
        reason = self._unavailable()
        if reason is not None:
            return json_response(403, {"error": reason})
        try:
            return json_response(200, work())
        except Refused as refused:
            return json_response(refused.status, {"error": refused.error, **refused.extra})
        except EnrollmentError as exc:
            return json_response(400, {"error": str(exc)})

    def capture_floor(self, request: Request) -> Response:
        return self._serve(self._capture)

    def _capture(self) -> dict[str, Any]:
        frame, result = self._newest()
        floor = Floor(frame.image.copy(), "floor", frame.index, frame.t_capture_s)
        with self._lock:
            self._floor = floor
        warnings = []
        # this frame's rovers and those seen within the last second: a rover the tracker lost for a frame or two
        # (it was moved, the scene jumped) is still on the floor
        recent = {r.id for r in self.camera.snapshot().rovers if (r.last_seen_age_s or math.inf) <= RECENT_S}
        seen = sorted({e.rover_id for e in (result.estimates if result is not None else ())} | recent)
        if seen:
            warnings.append(
                f"the tracker sees {', '.join(seen)} in this frame or the last second: if a rover is on the floor, "
                "take it away and capture again"
            )
        log.info("dashboard: empty floor captured (frame %d)", frame.index)
        return {"floor": floor.describe(), "warnings": warnings}

    def forget_floor(self, request: Request) -> Response:
        def forget() -> dict[str, Any]:
            with self._lock:
                self._floor = None
            return {"floor": None}

        return self._serve(forget)

    def floor_jpeg(self, request: Request) -> Response:
        with self._lock:
            floor = self._floor
        if floor is None:
            return json_response(404, {"error": "no empty floor captured"})
        jpeg, _, _ = encode_jpeg(floor.image, max_width_px=640, quality=80)
        return Response(200, jpeg, "image/jpeg")

    def post_enroll(self, request: Request) -> Response:
        return self._serve(lambda: self._enroll(parse_body(request.body, EnrolRequest, "enrolment request")))

    def _enroll(self, req: EnrolRequest) -> dict[str, Any]:
        calibration = self.calibration
        if calibration is None:
            raise Refused(403, "enrolment needs the calibration, and this edge has none")
        if not self._busy.acquire(blocking=False):
            raise Refused(409, "an enrolment is running: wait for its answer")
        try:
            frame, result = self._newest()
            floor = self._background(req.background, frame)
            if floor.image.shape != frame.image.shape:
                h, w = frame.image.shape[:2]
                fh, fw = floor.image.shape[:2]
                raise Refused(400, f"the empty floor is {fw}x{fh} but the camera now sends {w}x{h}: capture it again")
            ids = [i.strip() for i in req.ids if i.strip()] if req.ids else None
            length_cm, width_cm = self.marker_size_cm
            if floor.kind == "tracker" and result is not None:
                places = [(e.x_cm, e.y_cm) for e in result.estimates]
                hidden = in_background(frame.image, floor.image, calibration, places, 0.25 * width_cm)
                if hidden is not None:
                    e = result.estimates[hidden]
                    raise Refused(
                        400,
                        f"the tracker's background model has {e.rover_id} in it at ({e.x_cm:.0f}, {e.y_cm:.0f}) cm: "
                        "it learned the rover as floor while it did not track it there; enroll again once it has "
                        "moved, or capture the empty floor",
                    )
            enrolment = enroll(
                frame.image,
                floor.image,
                calibration,
                ids=ids or None,
                marker_length_cm=length_cm,
                marker_width_cm=width_cm,
            )
        finally:
            self._busy.release()
        where = f"frame {frame.index}{f' of {self.source}' if self.source else ''}"
        with self._lock:
            self._count += 1
            done = _Done(self._count, enrolment, enrolment.toml(where, by="the dashboard"))
            self._last = done
        warnings = list(enrolment.warnings)
        tracked = [] if result is None else result.estimates
        if floor.kind == "tracker" and len(tracked) != len(enrolment.markers):
            warnings.append(
                f"the tracker tracks {_rovers(len(tracked))} in this frame but {len(enrolment.markers)} markers differ "
                "from its background model, which learns any rover it does not track into the floor: to enroll new "
                "rovers, capture the empty floor first"
            )
        log.info(
            "dashboard: enrolled %s (frame %d, against the %s)",
            ", ".join(f"{m.rover_id} {m.color_bgr}" for m in enrolment.markers),
            frame.index,
            "captured floor" if floor.kind == "floor" else "tracker's background model",
        )
        return {
            "enrolment": done.number,
            "frame": frame.index,
            "image": {"width": enrolment.image_size[0], "height": enrolment.image_size[1]},
            "background": floor.describe(),
            "markers": [marker_json(m, tracked_on(m, result)) for m in enrolment.markers],
            "warnings": warnings,
            "ignored": list(enrolment.ignored),
            "toml": done.toml,
        }

    def post_save(self, request: Request) -> Response:
        return self._serve(lambda: self._save(parse_body(request.body, SaveRequest, "save request")))

    def _save(self, req: SaveRequest) -> dict[str, Any]:
        path = self.rovers_file
        if path is None:
            raise Refused(404, "no rovers file is configured (dashboard.rovers_file): download the file instead")
        with self._lock:
            last = self._last
        if last is None or last.number != req.enrolment:
            newest = "none was made" if last is None else f"the newest is {last.number}"
            raise Refused(409, f"enrolment {req.enrolment} is not the newest ({newest}): enroll again")
        existed = path.exists()
        if existed and not req.replace:
            raise Refused(409, f"{path} exists: replace it?", exists=True)
        save_enrolment(last.enrolment, path, text=last.toml)
        how = "replaced" if existed else "written"
        log.info("dashboard: %s %s with %d rovers", how, path, len(last.enrolment.markers))
        return {"saved": str(path), "replaced": existed, "rovers": [m.rover_id for m in last.enrolment.markers]}
