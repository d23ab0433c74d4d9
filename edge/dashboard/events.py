"""Server-sent events for the dashboard: what the page is told, built once per tick for every viewer.

The pure part turns a :class:`FrameResult` and a :class:`Snapshot` into the JSON the page reads (``pose_event``,
``status_event``; ``rovers_event`` from the rovers' own statuses), projecting each marker's outline and heading into
the image with the calibration so the browser draws the overlays. :class:`EventHub` runs one thread, only while a
page is connected, that reads the runtime's newest result (a reference read, never a lock the tracker waits on),
builds each event once and hands it to every viewer's small queue; a slow viewer loses its oldest events, nobody
else waits for it.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from edge.priority import background_priority

if TYPE_CHECKING:
    from edge.calibration import Calibration
    from edge.messages import RoverStatusV2
    from edge.metrics import Snapshot
    from edge.tracking import FrameResult

FloatArray = NDArray[np.float64]

SAMPLES_PER_SIDE = 4  # points per marker side in the outline, so lens curvature shows on wide lenses
HEADING_ARROW_CM = 30.0
KEEPALIVE_S = 15.0


# -- the pure part -------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Overlay:
    """Projects world-plane shapes into the camera image for the page's overlays.

    ``calibration``: the tracker's (marker plane); None when unknown (then the page gets no outlines).
    Marker sides in cm: ``length`` along the rover's heading, ``width`` across it (paper Table II: 21.5 x 16.8).
    """

    calibration: Calibration | None
    marker_length_cm: float = 21.5
    marker_width_cm: float = 16.8

    def marker_outlines_px(self, xy_world_cm: FloatArray, theta_rad: FloatArray) -> FloatArray:
        """(N, 2) marker centres, (N,) headings -> (N, 4 * SAMPLES_PER_SIDE, 2) outline pixels (NaN if unknown)."""
        n = xy_world_cm.shape[0]
        k = SAMPLES_PER_SIDE
        half_l, half_w = self.marker_length_cm / 2.0, self.marker_width_cm / 2.0
        corners = np.array([[half_l, half_w], [-half_l, half_w], [-half_l, -half_w], [half_l, -half_w]])
        t = np.arange(k) / k
        local = np.vstack([corners[i] + (corners[(i + 1) % 4] - corners[i]) * t[:, None] for i in range(4)])
        if self.calibration is None or n == 0:
            return np.full((n, local.shape[0], 2), np.nan)
        c, s = np.cos(theta_rad), np.sin(theta_rad)
        rot = np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)  # (N, 2, 2)
        world = xy_world_cm[:, None, :] + np.einsum("nij,kj->nki", rot, local)
        return self.calibration.world_to_pixel(world.reshape(-1, 2)).reshape(n, -1, 2)

    def heading_tips_px(self, xy_world_cm: FloatArray, theta_rad: FloatArray) -> FloatArray:
        """(N, 2) pixels of the point ``HEADING_ARROW_CM`` ahead of each rover (NaN without a calibration)."""
        if self.calibration is None or xy_world_cm.shape[0] == 0:
            return np.full((xy_world_cm.shape[0], 2), np.nan)
        tips = xy_world_cm + HEADING_ARROW_CM * np.column_stack([np.cos(theta_rad), np.sin(theta_rad)])
        return self.calibration.world_to_pixel(tips)

    def area_px(self, samples_per_edge: int = 32) -> list[list[float]]:
        """The working area's outline in image pixels, sampled densely (empty without a calibration)."""
        if self.calibration is None:
            return []
        from edge.calibration.errormap import area_outline_px

        outline = area_outline_px(self.calibration, samples_per_edge)
        return [[round(float(u), 1), round(float(v), 1)] for u, v in outline if math.isfinite(u) and math.isfinite(v)]


def _r(value: float | None, ndigits: int) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), ndigits) + 0.0


def pose_event(result: FrameResult, overlay: Overlay, rover_ids: Sequence[str] | None = None) -> dict[str, Any]:
    """The ``pose`` event of one frame: ``{frame, t, rovers: [...], missing: [...]}``.

    Each rover: world ``x, y`` cm, ``theta`` rad, ``vx, vy`` cm/s, quality ``q``, image ``u, v`` px, and when the
    calibration and heading are known its marker ``outline`` (list of ``[u, v]``) and heading tip ``head_u, head_v``.
    ``rover_ids``: the configured rovers; estimates of others are left out.
    """
    known = set(rover_ids) if rover_ids is not None else None
    estimates = [e for e in result.estimates if known is None or e.rover_id in known]
    with_heading = [e for e in estimates if e.theta_rad is not None and math.isfinite(e.theta_rad)]
    xy = np.array([[e.x_cm, e.y_cm] for e in with_heading], dtype=np.float64).reshape(-1, 2)
    theta = np.array([e.theta_rad for e in with_heading], dtype=np.float64)
    outlines = overlay.marker_outlines_px(xy, theta)
    tips = overlay.heading_tips_px(xy, theta)
    drawn = {e.rover_id: k for k, e in enumerate(with_heading)}
    rovers: list[dict[str, Any]] = []
    for e in estimates:
        item: dict[str, Any] = {
            "id": e.rover_id,
            "x": _r(e.x_cm, 2),
            "y": _r(e.y_cm, 2),
            "theta": _r(e.theta_rad, 4),
            "vx": _r(e.vx_cm_s, 2),
            "vy": _r(e.vy_cm_s, 2),
            "q": _r(e.quality, 3),
            "u": _r(e.uv_px[0], 1),
            "v": _r(e.uv_px[1], 1),
        }
        k = drawn.get(e.rover_id)
        if k is not None and np.all(np.isfinite(outlines[k])):
            item["outline"] = [[round(float(u), 1), round(float(v), 1)] for u, v in outlines[k]]
        if k is not None and np.all(np.isfinite(tips[k])):
            item["head_u"], item["head_v"] = round(float(tips[k, 0]), 1), round(float(tips[k, 1]), 1)
        rovers.append(item)
    missing = [m for m in result.missing if known is None or m in known]
    return {"frame": result.frame_index, "t": _r(result.t_capture_s, 3), "rovers": rovers, "missing": missing}


def status_event(snap: Snapshot) -> dict[str, Any]:
    """The ``status`` event: edge state, camera, broker, fps, latency percentiles (ms) and each rover's freshness."""

    def ms(seconds: float) -> float | None:
        return _r(seconds * 1000.0, 2)

    return {
        "state": snap.state,
        "reason": snap.reason,
        "camera": snap.camera,
        "broker": "connected" if snap.broker_connected else "disconnected",
        "fps": _r(snap.fps, 2) or 0.0,
        "frames": snap.frames_processed,
        "latency_ms": {"p50": ms(snap.end_to_end.p50_s), "p99": ms(snap.end_to_end.p99_s)},
        "processing_ms": {"p50": ms(snap.processing.p50_s), "p99": ms(snap.processing.p99_s)},
        "rovers": {
            r.id: {"last_seen_s": _r(r.last_seen_age_s, 2), "rate_hz": _r(r.rate_hz, 2) or 0.0, "q": _r(r.quality, 3)}
            for r in snap.rovers
        },
    }


def rovers_event(
    rover_ids: Sequence[str], reports: Mapping[str, RoverStatusV2], retained: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The ``rovers`` event (and ``GET /api/rovers``): what each configured rover says it applies, from its retained
    rover status, and whether that is the broker's retained formation (same kind and seq).

    ``{"retained": {kind, seq} or null, "rovers": [{id, reported, state, halt, formation, seq, fw, on_retained}]}``;
    a rover that has published no status has ``reported: false`` and nothing else.
    """
    held = None if retained is None else (retained["kind"], retained["seq"])
    rows: list[dict[str, Any]] = []
    for rover_id in rover_ids:
        r = reports.get(rover_id)
        if r is None:
            rows.append({"id": rover_id, "reported": False})
            continue
        rows.append(
            {
                "id": rover_id,
                "reported": True,
                "state": r.state,
                "halt": r.halt,
                "formation": r.formation,
                "seq": r.seq,
                "fw": r.fw,
                "on_retained": r.formation is not None and (r.formation, r.seq) == held,
            }
        )
    return {"retained": None if held is None else {"kind": held[0], "seq": held[1]}, "rovers": rows}


def sse(event: str, data: Any) -> bytes:
    """One server-sent event (``event:`` and one ``data:`` line of compact JSON)."""
    body = json.dumps(data, separators=(",", ":"), allow_nan=False)
    return f"event: {event}\ndata: {body}\n\n".encode()


# -- the hub -------------------------------------------------------------------------------------------------------
class _Viewer:
    __slots__ = ("dropped", "queue")

    def __init__(self, size: int) -> None:
        self.queue: deque[bytes] = deque(maxlen=size)
        self.dropped = 0


class EventHub:
    """Builds pose events at ``pose_hz`` (only for new results) and status events every ``status_interval_s``,
    once for all viewers, on its own thread that runs only while a viewer is connected.

    ``latest``: returns the newest tracker result (read, never waited on). ``make_pose``, ``make_status``: build
    the event data. :meth:`publish` adds other events (formation changes).
    """

    def __init__(
        self,
        *,
        latest: Callable[[], FrameResult | None],
        make_pose: Callable[[FrameResult], dict[str, Any]],
        make_status: Callable[[], dict[str, Any]],
        pose_hz: float = 15.0,
        status_interval_s: float = 1.0,
        queue_size: int = 32,
        wait_next: Callable[[float], None] | None = None,
    ) -> None:
        self._latest = latest
        self._wait_next = wait_next
        self._make_pose = make_pose
        self._make_status = make_status
        self.pose_period_s = 1.0 / pose_hz
        self.status_interval_s = status_interval_s
        self._queue_size = queue_size
        self._cond = threading.Condition()
        self._viewers: set[_Viewer] = set()
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None
        self.pose_events = 0
        self.status_events = 0

    @property
    def viewers(self) -> int:
        with self._cond:
            return len(self._viewers)

    def publish(self, event: str, data: Any) -> None:
        """Send an event to every connected viewer now."""
        self._broadcast(sse(event, data))

    def _broadcast(self, chunk: bytes) -> None:
        with self._cond:
            for viewer in self._viewers:
                if len(viewer.queue) == viewer.queue.maxlen:
                    viewer.dropped += 1  # deque(maxlen) drops the oldest: a slow page loses old poses only
                viewer.queue.append(chunk)
            self._cond.notify_all()

    def _run(self) -> None:
        background_priority()
        last: FrameResult | None = None
        next_pose = 0.0
        next_status = 0.0
        while not self._closed.is_set():
            with self._cond:
                self._cond.wait_for(lambda: bool(self._viewers) or self._closed.is_set())
            if self._closed.is_set():
                break
            # With wait_next (the appliance), built just after the tracker publishes a result, so the work falls in
            # the gap before the next frame rather than beside the tracker; at most pose_hz events a second.
            result = self._latest()
            now = time.monotonic()
            if result is not None and result is not last and now >= next_pose:
                last = result
                next_pose = now + 0.85 * self.pose_period_s  # results come on the camera's clock: every 2nd at 15 Hz
                self._broadcast(sse("pose", self._make_pose(result)))
                self.pose_events += 1
                if now >= next_status:
                    self._broadcast(sse("status", self._make_status()))
                    self.status_events += 1
                    next_status = now + self.status_interval_s
            elif now >= next_status + self.status_interval_s:  # no frames: the status still says so
                self._broadcast(sse("status", self._make_status()))
                self.status_events += 1
                next_status = now + self.status_interval_s
            if self._wait_next is not None:
                self._wait_next(0.25)
            else:
                self._closed.wait(self.pose_period_s)

    def _ensure_thread(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="dashboard-events", daemon=True)
            self._thread.start()

    def stream(self, first: Sequence[tuple[str, Any]] = (), keepalive_s: float = KEEPALIVE_S) -> Iterator[bytes]:
        """The body of one ``text/event-stream`` response: ``first`` events at once, then everything published,
        with a comment line as keep-alive. Ends when the hub closes (or the client goes away)."""
        background_priority()  # this is the request's thread, which only serves the page
        viewer = _Viewer(self._queue_size)
        with self._cond:
            if self._closed.is_set():
                return
            self._viewers.add(viewer)
            self._ensure_thread()
            self._cond.notify_all()
        try:
            yield b"retry: 2000\n\n" + b"".join(sse(name, data) for name, data in first)
            while True:
                with self._cond:
                    self._cond.wait_for(lambda: bool(viewer.queue) or self._closed.is_set(), timeout=keepalive_s)
                    if self._closed.is_set():
                        return
                    chunks = list(viewer.queue)
                    viewer.queue.clear()
                yield b"".join(chunks) if chunks else b": keep-alive\n\n"
        finally:
            with self._cond:
                self._viewers.discard(viewer)

    def close(self) -> None:
        """End every stream and the thread."""
        with self._cond:
            self._closed.set()
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
