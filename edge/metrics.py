"""What the runtime knows about itself: rolling latency windows, a snapshot of its state, Prometheus text.

The runtime fills :class:`LatencyWindow` objects on its hot path (a preallocated ring, no allocation per sample)
and builds a :class:`Snapshot` on request; ``/healthz``, ``/metrics`` and the dashboard read snapshots only.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

QUANTILES = (0.5, 0.9, 0.99)


class LatencyWindow:
    """The last ``size`` samples (seconds) in a ring buffer, with a running count and sum for Prometheus."""

    def __init__(self, size: int = 3000) -> None:
        self._ring = np.zeros(size, dtype=np.float64)
        self._next = 0
        self._filled = 0
        self._lock = threading.Lock()
        self.count = 0
        self.total_s = 0.0

    def add(self, seconds: float) -> None:
        with self._lock:
            self._ring[self._next] = seconds
            self._next = (self._next + 1) % self._ring.size
            self._filled = min(self._filled + 1, self._ring.size)
            self.count += 1
            self.total_s += seconds

    def quantiles(self, qs: Sequence[float] = QUANTILES) -> tuple[float, ...]:
        """Quantiles of the window (NaN while empty)."""
        with self._lock:
            data = self._ring[: self._filled].copy()
        if data.size == 0:
            return tuple(math.nan for _ in qs)
        return tuple(float(v) for v in np.quantile(data, qs))


class RateMeter:
    """Events per second over the last ``window_s`` (a ring of event times; enough for ``size / window_s`` Hz)."""

    def __init__(self, window_s: float = 2.0, size: int = 1024) -> None:
        self.window_s = window_s
        self._times = np.full(size, -math.inf, dtype=np.float64)
        self._next = 0
        self._lock = threading.Lock()

    def tick(self, t_mono_s: float) -> None:
        with self._lock:
            self._times[self._next] = t_mono_s
            self._next = (self._next + 1) % self._times.size

    def rate(self, now_mono_s: float) -> float:
        with self._lock:
            recent = int(np.count_nonzero(self._times > now_mono_s - self.window_s))
        return recent / self.window_s


@dataclass(frozen=True)
class Latency:
    """Quantiles (seconds) of a latency window with its lifetime count and sum."""

    p50_s: float
    p90_s: float
    p99_s: float
    count: int
    total_s: float

    @classmethod
    def of(cls, window: LatencyWindow) -> Latency:
        p50, p90, p99 = window.quantiles(QUANTILES)
        return cls(p50, p90, p99, window.count, window.total_s)


@dataclass(frozen=True)
class RoverSnapshot:
    """One rover as the edge sees it now."""

    id: str
    detections: int
    missed: int
    last_seen_age_s: float | None
    rate_hz: float
    quality: float | None
    x_cm: float | None
    y_cm: float | None
    theta_rad: float | None


@dataclass(frozen=True)
class Snapshot:
    """The appliance's state at one moment, for /healthz, /metrics and the dashboard."""

    edge_id: str
    state: str  # online, degraded, offline
    reason: str  # why degraded, empty when online
    camera: str  # ok, starting, stalled, missing, stopped
    source: str
    broker: str
    uptime_s: float
    fps: float
    frames_processed: int
    frames_dropped: int
    processing: Latency
    end_to_end: Latency
    rovers: tuple[RoverSnapshot, ...]
    broker_connected: bool
    broker_connects: int
    broker_disconnects: int
    poses_sent: int
    poses_dropped: int
    poses_invalid: int
    camera_failures: int
    camera_reopens: int
    recording_lines: int
    recording_dropped: int

    def health(self) -> dict[str, object]:
        """The /healthz body."""
        return {
            "edge": self.edge_id,
            "state": self.state,
            "reason": self.reason,
            "camera": self.camera,
            "broker_connected": self.broker_connected,
            "fps": round(self.fps, 2),
            "uptime_s": round(self.uptime_s, 1),
            "rovers": {r.id: r.last_seen_age_s is not None and r.last_seen_age_s < 2.0 for r in self.rovers},
        }


def _escape(value: str) -> str:
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def _num(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    return repr(float(value)) if not float(value).is_integer() else str(int(value))


class _Writer:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def metric(self, name: str, kind: str, help_text: str, samples: Iterable[tuple[str, float]]) -> None:
        self.lines.append(f"# HELP edge_ips_{name} {help_text}")
        self.lines.append(f"# TYPE edge_ips_{name} {kind}")
        for labels, value in samples:
            self.lines.append(f"edge_ips_{name}{labels} {_num(value)}")

    def summary(self, name: str, help_text: str, latency: Latency) -> None:
        self.lines.append(f"# HELP edge_ips_{name} {help_text}")
        self.lines.append(f"# TYPE edge_ips_{name} summary")
        for q, v in zip(QUANTILES, (latency.p50_s, latency.p90_s, latency.p99_s), strict=True):
            self.lines.append(f'edge_ips_{name}{{quantile="{q}"}} {_num(v)}')
        self.lines.append(f"edge_ips_{name}_sum {_num(latency.total_s)}")
        self.lines.append(f"edge_ips_{name}_count {latency.count}")


STATES = ("online", "degraded", "offline")
CAMERA_STATES = ("ok", "starting", "stalled", "missing", "stopped")


def to_prometheus(s: Snapshot) -> str:
    """The Prometheus text exposition (format 0.0.4) of a snapshot."""
    w = _Writer()
    info = f'{{edge="{_escape(s.edge_id)}",source="{_escape(s.source)}",broker="{_escape(s.broker)}"}}'
    w.metric("info", "gauge", "Edge id, frame source and broker.", [(info, 1)])
    w.metric("state", "gauge", "1 for the current edge state.", [(f'{{state="{v}"}}', v == s.state) for v in STATES])
    w.metric(
        "camera_state",
        "gauge",
        "1 for the current frame source state.",
        [(f'{{state="{v}"}}', v == s.camera) for v in CAMERA_STATES],
    )
    w.metric("uptime_seconds", "gauge", "Seconds since start.", [("", s.uptime_s)])
    w.metric("fps", "gauge", "Frames processed per second over the last status interval.", [("", s.fps)])
    w.metric("frames_processed_total", "counter", "Frames the tracker processed.", [("", s.frames_processed)])
    w.metric(
        "frames_dropped_total",
        "counter",
        "Frames overwritten by a newer one before the tracker took them.",
        [("", s.frames_dropped)],
    )
    w.summary("processing_seconds", "Tracker time per frame (recent window).", s.processing)
    w.summary("end_to_end_seconds", "Frame grab to pose handed to the MQTT client (recent window).", s.end_to_end)
    rovers = [(f'{{rover="{_escape(r.id)}"}}', r) for r in s.rovers]
    w.metric(
        "detections_total", "counter", "Frames in which the rover was found.", [(k, r.detections) for k, r in rovers]
    )
    w.metric("missed_total", "counter", "Frames the rover was not found in.", [(k, r.missed) for k, r in rovers])
    w.metric(
        "rover_last_seen_seconds",
        "gauge",
        "Seconds since the rover was last found (NaN: never).",
        [(k, math.nan if r.last_seen_age_s is None else r.last_seen_age_s) for k, r in rovers],
    )
    w.metric("broker_connected", "gauge", "1 while connected to the MQTT broker.", [("", s.broker_connected)])
    w.metric("broker_connects_total", "counter", "Successful broker connections.", [("", s.broker_connects)])
    w.metric("broker_disconnects_total", "counter", "Broker connections lost.", [("", s.broker_disconnects)])
    w.metric("poses_published_total", "counter", "Pose messages published.", [("", s.poses_sent)])
    w.metric("poses_dropped_total", "counter", "Poses dropped while the broker was away.", [("", s.poses_dropped)])
    w.metric("poses_invalid_total", "counter", "Estimates the contract cannot carry.", [("", s.poses_invalid)])
    w.metric("camera_failures_total", "counter", "Times the frame source failed.", [("", s.camera_failures)])
    w.metric("camera_reopens_total", "counter", "Times the frame source was reopened.", [("", s.camera_reopens)])
    w.metric("recording_lines_total", "counter", "Lines written to the recording.", [("", s.recording_lines)])
    w.metric("recording_dropped_total", "counter", "Lines the recording could not keep.", [("", s.recording_dropped)])
    return "\n".join(w.lines) + "\n"
