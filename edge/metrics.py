"""What the runtime knows about itself: rolling latency windows, a snapshot of its state, Prometheus metrics.

The runtime fills :class:`LatencyWindow` objects on its hot path (a preallocated ring, no allocation per sample)
and builds a :class:`Snapshot` on request; ``/healthz``, ``/metrics`` and the dashboard read snapshots only.
``/metrics`` is ``prometheus_client``'s exposition of a registry whose collectors build their families from a
snapshot (and the HTTP server's and recorder's counters) when scraped: the tracker's thread does nothing for it.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from prometheus_client import CollectorRegistry, ProcessCollector, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_PLAIN_0_0_4
from prometheus_client.metrics_core import CounterMetricFamily, GaugeMetricFamily, Metric

if TYPE_CHECKING:
    from edge.httpserver import HttpServer
    from edge.recording import Recorder

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
    poses_held: int = 0  # after a broker (re)connection, until the edge's retained stop was acknowledged

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


STATES = ("online", "degraded", "offline")
CAMERA_STATES = ("ok", "starting", "stalled", "missing", "stopped")
CONTENT_TYPE = CONTENT_TYPE_PLAIN_0_0_4


def _gauge(name: str, help_text: str, value: float) -> GaugeMetricFamily:
    return GaugeMetricFamily(f"edge_ips_{name}", help_text, value=float(value))


def _counter(name: str, help_text: str, value: float) -> CounterMetricFamily:
    return CounterMetricFamily(f"edge_ips_{name}", help_text, value=float(value))


def _summary(name: str, help_text: str, latency: Latency) -> Metric:
    # prometheus_client's SummaryMetricFamily has no quantiles; the runtime's windows have them.
    metric = Metric(f"edge_ips_{name}", help_text, "summary")
    for q, v in zip(QUANTILES, (latency.p50_s, latency.p90_s, latency.p99_s), strict=True):
        metric.add_sample(f"edge_ips_{name}", {"quantile": str(q)}, v)
    metric.add_sample(f"edge_ips_{name}_sum", {}, latency.total_s)
    metric.add_sample(f"edge_ips_{name}_count", {}, latency.count)
    return metric


def _one_of(name: str, help_text: str, values: Sequence[str], current: str) -> GaugeMetricFamily:
    family = GaugeMetricFamily(f"edge_ips_{name}", help_text, labels=["state"])
    for value in values:
        family.add_metric([value], 1.0 if value == current else 0.0)
    return family


def _per_rover(name: str, kind: str, help_text: str, samples: Iterable[tuple[str, float]]) -> Metric:
    family: GaugeMetricFamily | CounterMetricFamily
    if kind == "counter":
        family = CounterMetricFamily(f"edge_ips_{name}", help_text, labels=["rover"])
    else:
        family = GaugeMetricFamily(f"edge_ips_{name}", help_text, labels=["rover"])
    for rover, value in samples:
        family.add_metric([rover], float(value))
    return family


def snapshot_metrics(s: Snapshot) -> Iterator[Metric]:
    """The metric families of one snapshot."""
    info = GaugeMetricFamily("edge_ips_info", "Edge id, frame source and broker.", labels=["edge", "source", "broker"])
    info.add_metric([s.edge_id, s.source, s.broker], 1.0)
    yield info
    yield _one_of("state", "1 for the current edge state.", STATES, s.state)
    yield _one_of("camera_state", "1 for the current frame source state.", CAMERA_STATES, s.camera)
    yield _gauge("uptime_seconds", "Seconds since start.", s.uptime_s)
    yield _gauge("fps", "Frames processed per second over the last status interval.", s.fps)
    yield _counter("frames_processed", "Frames the tracker processed.", s.frames_processed)
    yield _counter(
        "frames_dropped", "Frames overwritten by a newer one before the tracker took them.", s.frames_dropped
    )
    yield _summary("processing_seconds", "Tracker time per frame (recent window).", s.processing)
    yield _summary("end_to_end_seconds", "Frame grab to pose handed to the MQTT client (recent window).", s.end_to_end)
    yield _per_rover(
        "detections", "counter", "Frames in which the rover was found.", [(r.id, r.detections) for r in s.rovers]
    )
    yield _per_rover("missed", "counter", "Frames the rover was not found in.", [(r.id, r.missed) for r in s.rovers])
    yield _per_rover(
        "rover_last_seen_seconds",
        "gauge",
        "Seconds since the rover was last found (NaN: never).",
        [(r.id, math.nan if r.last_seen_age_s is None else r.last_seen_age_s) for r in s.rovers],
    )
    yield _gauge("broker_connected", "1 while connected to the MQTT broker.", s.broker_connected)
    yield _counter("broker_connects", "Successful broker connections.", s.broker_connects)
    yield _counter("broker_disconnects", "Broker connections lost.", s.broker_disconnects)
    yield _counter("poses_published", "Pose messages published.", s.poses_sent)
    yield _counter("poses_dropped", "Poses dropped while the broker was away.", s.poses_dropped)
    yield _counter(
        "poses_held", "Poses held back after a broker connection until the edge's stop was acknowledged.", s.poses_held
    )
    yield _counter("poses_invalid", "Estimates the contract cannot carry.", s.poses_invalid)
    yield _counter("camera_failures", "Times the frame source failed.", s.camera_failures)
    yield _counter("camera_reopens", "Times the frame source was reopened.", s.camera_reopens)
    yield _counter("recording_lines", "Whole lines written to the recording.", s.recording_lines)
    yield _counter("recording_dropped", "Lines the recording could not keep.", s.recording_dropped)
    yield _gauge("threads", "Threads in the process.", threading.active_count())


class _Collect:
    """A prometheus_client collector calling ``make()`` at each scrape (nothing runs between scrapes)."""

    def __init__(self, make: Callable[[], Iterable[Metric]]) -> None:
        self._make = make

    def collect(self) -> Iterable[Metric]:
        return self._make()


def http_metrics(server: HttpServer) -> Iterator[Metric]:
    """The HTTP server's connections, refusals and responses."""
    st = server.stats
    yield _gauge("http_connections_open", "Open HTTP connections.", server.open_connections)
    yield _counter("http_connections", "HTTP connections accepted.", st.connections)
    yield _counter("http_connections_evicted", "Idle connections closed to make room for a new one.", st.evicted)
    yield _counter("http_connections_refused", "New connections closed because every one was busy.", st.refused)
    yield _counter("http_request_timeouts", "Connections closed for not sending a request in time.", st.timed_out)
    yield _gauge("http_streams_open", "Open event streams.", st.streams_open)
    yield _counter("http_host_refused", "Requests refused for a Host that is not the board's.", st.host_refused)
    limiter = server.guard.limiter
    yield _counter("http_auth_failures", "Requests with a wrong token.", limiter.failures)
    yield _counter("http_auth_lockouts", "Addresses locked out after repeated wrong tokens.", limiter.lockouts)
    yield _counter("http_auth_refused", "Requests refused from a locked-out address.", limiter.refused)
    responses = CounterMetricFamily("edge_ips_http_responses", "HTTP responses by status code.", labels=["code"])
    for code, count in sorted(dict(st.responses).items()):
        responses.add_metric([str(code)], float(count))
    yield responses


def recording_metrics(recorder: Recorder) -> Iterator[Metric]:
    yield _gauge("recording_paused", "1 while the recording is paused (disk full or not writable).", recorder.paused)
    yield _gauge("recording_files", "Recording files kept in the directory.", len(recorder.files))


def metrics_registry(
    snapshot: Callable[[], Snapshot], *, http: HttpServer | None = None, recorder: Recorder | None = None
) -> CollectorRegistry:
    """A registry that builds everything at scrape time: the snapshot, the HTTP server's and the recorder's
    counters, and the process (CPU seconds, memory, open files)."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Collect(lambda: snapshot_metrics(snapshot())))
    if http is not None:
        registry.register(_Collect(lambda: http_metrics(http)))
    if recorder is not None:
        registry.register(_Collect(lambda: recording_metrics(recorder)))
    ProcessCollector(registry=registry)
    return registry


def exposition(registry: CollectorRegistry) -> tuple[bytes, str]:
    """The Prometheus text exposition (format 0.0.4) of ``registry`` and its content type."""
    return generate_latest(registry), CONTENT_TYPE
