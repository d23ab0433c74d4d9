"""The appliance's main job: frames in, poses out, for weeks.

Threads and what they share:

* ``capture`` (:class:`edge.capture.CaptureThread`) reads the source into a newest-frame :class:`FrameSlot`;
* ``tracker`` (:class:`EdgeRuntime`) takes the newest frame, runs the tracker, publishes one pose per rover
  (:func:`edge.poses.publish_poses`, the rule the simulator's closed loop uses too);
* ``status`` publishes the retained edge status every ``status_interval_s`` and at once after a reconnect;
* paho's network thread (reconnects with backoff), the recorder's writer, the HTTP server, the embedded broker.

They talk through the slot, ``threading.Event`` for stop, and the recorder's bounded queue. Stopping publishes
the ``offline`` status, waits for the broker's acknowledgement, then flushes the recording.

:mod:`edge.appliance` assembles it, and everything around it, from the configuration.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from edge.board_messages import detections_topic
from edge.capture import CaptureThread, FrameSlot
from edge.clock import SYSTEM_CLOCK, Clock
from edge.errors import MessageError
from edge.fusion.board import listed_rovers
from edge.fusion.detections import encode_detections
from edge.fusion.uncertainty import DetectionBuilder
from edge.messages import StatusV1
from edge.metrics import Latency, LatencyWindow, RateMeter, RoverSnapshot, Snapshot
from edge.poses import publish_poses
from edge.publisher import Publisher, offline_status
from edge.sources import FrameSource, SourceInfo
from edge.tracking import Frame, FrameResult, RoverEstimate, Tracker

log = logging.getLogger("edge.runtime")


@dataclass(frozen=True)
class _Pose:
    """A rover's newest published pose, for the snapshot."""

    x_cm: float
    y_cm: float
    theta_rad: float | None
    quality: float


class _RoverStats:
    __slots__ = ("detections", "id", "last", "last_seen_mono", "missed", "rate")

    def __init__(self, rover_id: str) -> None:
        self.id = rover_id
        self.detections = 0
        self.missed = 0
        self.last_seen_mono: float | None = None
        self.last: _Pose | None = None
        self.rate = RateMeter()

    def saw(self, est: RoverEstimate, t_mono_s: float) -> None:
        self.detections += 1
        self.last_seen_mono = t_mono_s
        self.last = _Pose(est.x_cm, est.y_cm, est.theta_rad, est.quality)
        self.rate.tick(t_mono_s)


class EdgeRuntime:
    """Source -> tracker -> publisher, on threads, with status, metrics and a clean stop.

    ``source`` must already be open (``info`` is what it granted). ``tap`` is not needed here: recording hangs
    off the publisher. ``clock`` times everything the status says (ages, rates, stalls; the frames carry the
    source's own stamps, which should come from the same clock).
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
        clock: Clock = SYSTEM_CLOCK,
        detections: DetectionBuilder | None = None,
    ) -> None:
        self.edge_id = edge_id
        self.detections = detections  # a board of several: publish detections, not poses
        self.clock = clock
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
            source,
            self.slot,
            self.stop_event,
            info=info,
            reopen_min_s=reopen_min_s,
            reopen_max_s=reopen_max_s,
            clock=clock,
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
        self._seq = dict.fromkeys(self.rover_ids, 0)  # each rover's next pose seq (edge.poses)
        self._status_due = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started_mono = self.clock.monotonic()
        self._last_state: tuple[str, str] = ("", "")
        self._stopped = False

    # -- the hot path -------------------------------------------------------------------------------------------
    def _publish_result(self, result: FrameResult, frame_index: int, t_capture_s: float) -> None:
        out = publish_poses(self.publisher, result.estimates, self._seq, frame_index, t_capture_s)
        for _, exc in out.invalid:
            self.poses_invalid += 1
            if self.poses_invalid in (1, 10, 100, 1000) or self.poses_invalid % 10000 == 0:
                log.warning("pose not publishable (%d so far): %s", self.poses_invalid, exc)
        invalid = {rover_id for rover_id, _ in out.invalid}
        seen = set()
        for est in out.seen:
            if est.rover_id in invalid:
                continue
            seen.add(est.rover_id)
            self._rovers[est.rover_id].saw(est, result.t_mono_s)
        self._count_missed(seen)

    def _publish_detections(self, result: FrameResult, frame: Frame, builder: DetectionBuilder) -> None:
        """A board of several: this frame's detections for the fuser instead of poses."""
        try:
            payload = encode_detections(builder.build(result, frame.image, t_sent_s=self.clock.wall()))
        except MessageError as exc:
            self.poses_invalid += 1
            if self.poses_invalid in (1, 10, 100, 1000) or self.poses_invalid % 10000 == 0:
                log.warning("detections not publishable (%d so far): %s", self.poses_invalid, exc)
            return
        self.publisher.publish(detections_topic(self.edge_id), payload)
        seen = set()
        for est in result.estimates:
            stats = self._rovers.get(est.rover_id)
            if stats is not None:
                seen.add(est.rover_id)
                stats.saw(est, result.t_mono_s)
        self._count_missed(seen)

    def _count_missed(self, seen: set[str]) -> None:
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
            t0 = self.clock.monotonic()
            result = self.tracker.process(frame)
            t1 = self.clock.monotonic()
            if self.detections is not None:
                self._publish_detections(result, frame, self.detections)
            else:
                self._publish_result(result, frame.index, frame.t_capture_s)
            t2 = self.clock.monotonic()
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

    def newest_frame(self) -> Frame | None:
        """The newest captured frame, tracked or not (the dashboard's calibration panel draws on it)."""
        return self.slot.peek()

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
            return "starting" if self.clock.monotonic() - self._started_mono < self.stall_timeout_s else "stalled"
        if self.clock.monotonic() - self.capture.last_frame_mono > self.stall_timeout_s:
            return "stalled"
        return "ok"

    @property
    def settle_s(self) -> float:
        """How long a rover may go unseen before it counts as missing; also the start-up grace before the first
        rover missing makes the state ``degraded``."""
        return max(self.status_interval_s, 1.0)

    @property
    def tracking_for_s(self) -> float:
        """Seconds since the first tracked frame (0 before it)."""
        return 0.0 if self._first_result_mono is None else self.clock.monotonic() - self._first_result_mono

    def _seen_recently(self, now: float) -> tuple[list[str], list[str]]:
        window = self.settle_s
        seen: list[str] = []
        missing: list[str] = []
        for rover_id, stats in self._rovers.items():
            fresh = stats.last_seen_mono is not None and now - stats.last_seen_mono <= window
            (seen if fresh else missing).append(rover_id)
        return seen, missing

    def _state(self, camera: str, missing: list[str]) -> tuple[str, str]:
        if camera not in ("ok", "starting"):
            return "degraded", f"camera {camera}" + (f": {self.capture.problem}" if self.capture.problem else "")
        if camera == "ok" and missing and self.tracking_for_s > self.settle_s:
            return "degraded", f"not seen: {', '.join(missing)}"
        return "online", ""

    def current_status(self) -> StatusV1:
        now = self.clock.monotonic()
        camera = self.camera_state()
        seen, missing = self._seen_recently(now)
        if self.detections is not None:  # a board of several: the others' rovers are not missing here
            seen, missing = listed_rovers(seen), []
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
            t=round(self.clock.wall(), 3),
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
        self._started_mono = self.clock.monotonic()
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

    def wait_finished(self, timeout_s: float) -> bool:
        """Block until the tracker has stopped (the source ended, a thread failed, or stop); False on timeout."""
        self._threads[0].join(timeout_s)
        return not self._threads[0].is_alive()

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
        self.tracker.close()  # a tracker with a worker (edge.centre_offsets) stops it
        missing = self.rover_ids if self.detections is None else ()  # a board of several calls nobody missing
        self.publisher.stop(offline_status(self.edge_id, missing), timeout_s=timeout_s)
        if self.recorder is not None:
            self.recorder.close()
        log.info("stopped after %d frames; offline status published", self.frames_processed)

    # -- for /metrics, /healthz and the dashboard ---------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        now = self.clock.monotonic()
        camera = self.camera_state() if not self._stopped else "stopped"
        _, missing = self._seen_recently(now)
        missing = missing if self.detections is None else []
        state, reason = self._state(camera, missing) if not self._stopped else ("offline", "stopped")
        rovers = tuple(
            RoverSnapshot(
                id=s.id,
                detections=s.detections,
                missed=s.missed,
                last_seen_age_s=None if s.last_seen_mono is None else now - s.last_seen_mono,
                rate_hz=s.rate.rate(now),
                quality=None if s.last is None else s.last.quality,
                x_cm=None if s.last is None else s.last.x_cm,
                y_cm=None if s.last is None else s.last.y_cm,
                theta_rad=None if s.last is None else s.last.theta_rad,
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
            poses_held=stats.poses_held,
        )
