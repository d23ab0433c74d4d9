"""The edge status (contract v1): online, degraded with the reason, offline on stop; poses as exact encode_pose
bytes. The runtime with the in-memory publisher (STYLE point 3), real threads, scripted sources and trackers."""

from __future__ import annotations

import json
import threading
from typing import Any

import pytest

from edge.clock import SYSTEM_CLOCK, ManualClock
from edge.messages import edge_status_topic, encode_pose, parse_pose, parse_status, pose_topic
from edge.publisher import MemoryPublisher
from edge.runtime import EdgeRuntime
from edge.sources import MemorySource, SourceInfo
from edge.tracking import Frame, FrameResult, RoverEstimate
from tests.support.runtime import scene

ROVERS = ("red", "green", "blue")


class ScriptedTracker:
    """Sees every rover, except those listed in ``hidden`` (changeable while running)."""

    def __init__(self) -> None:
        self.hidden: set[str] = set()

    def process(self, frame: Frame) -> FrameResult:
        seen = tuple(
            RoverEstimate(r, 10.0 * k + frame.index, 20.0, 0.5, 1.0, None, 0.9, (0.0, 0.0))
            for k, r in enumerate(ROVERS)
            if r not in self.hidden
        )
        missing = tuple(r for r in ROVERS if r in self.hidden)
        return FrameResult(frame.index, frame.t_capture_s, frame.t_mono_s, seen, missing, {})

    def reset(self) -> None:
        pass

    def close(self) -> None:
        pass


class GatedSource:
    """Frames at 30 fps while ``flowing`` is set; a read blocks (a stalled camera) while it is clear, and says so
    in ``blocked``. Frames are stamped by ``clock``."""

    def __init__(self, clock: ManualClock) -> None:
        self.flowing = threading.Event()
        self.flowing.set()
        self.blocked = threading.Event()
        self._inner = MemorySource([scene(i) for i in range(30)], loop=True, realtime=True, clock=clock)

    def open(self) -> SourceInfo:
        return self._inner.open()

    def read(self) -> Frame | None:
        if not self.flowing.is_set():
            self.blocked.set()
        self.flowing.wait()
        self.blocked.clear()
        return self._inner.read()

    def close(self) -> None:
        self.flowing.set()


def _runtime(source: Any, tracker: Any, publisher: MemoryPublisher, clock: ManualClock | None = None) -> EdgeRuntime:
    return EdgeRuntime(
        edge_id="edge-s",
        source=source,
        info=source.open(),
        tracker=tracker,
        publisher=publisher,
        rovers=ROVERS,
        status_interval_s=0.2,
        stall_timeout_s=0.5,
        clock=clock or SYSTEM_CLOCK,
    )


def _wait_status(pub: MemoryPublisher, predicate: Any, timeout_s: float = 20.0) -> dict[str, Any]:
    """The first status published (from now on, or the newest one) that satisfies ``predicate``."""
    topic = edge_status_topic("edge-s")
    found: list[dict[str, Any]] = []

    def matched() -> bool:
        payloads = pub.on(topic)
        found[:] = [json.loads(p) for p in payloads[-1:] if predicate(json.loads(p))]
        return bool(found)

    assert pub.wait_until(matched, timeout_s), f"no status matching; last: {pub.on(topic)[-1:]}"
    return found[0]


@pytest.mark.slow
def test_status_follows_rovers_and_camera_and_ends_offline() -> None:
    # Time is the runtime's clock, moved on by hand: a rover goes missing or the camera stalls the moment the clock
    # passes their windows (1 s unseen, 0.5 s without a frame), however slowly the threads run.
    clock = ManualClock()
    source, tracker, pub = GatedSource(clock), ScriptedTracker(), MemoryPublisher()
    runtime = _runtime(source, tracker, pub, clock).start()
    try:
        online = _wait_status(pub, lambda s: s["state"] == "online" and s["camera"] == "ok" and s["rovers"])
        assert online["rovers"] == list(ROVERS) and online["missing"] == []

        tracker.hidden = {"blue"}
        clock.advance(1.5)  # blue's last pose is now 1.5 s old; the next frames show red and green
        gone = _wait_status(pub, lambda s: s["missing"] == ["blue"])
        assert gone["state"] == "degraded" and gone["rovers"] == ["red", "green"]
        tracker.hidden = set()
        _wait_status(pub, lambda s: s["state"] == "online" and s["missing"] == [])

        source.flowing.clear()  # the camera stalls: a read that never returns
        assert source.blocked.wait(20.0)
        clock.advance(0.8)  # past the stall timeout, within the rovers' window
        stalled = _wait_status(pub, lambda s: s["camera"] == "stalled")
        assert stalled["state"] == "degraded"
        source.flowing.set()
        _wait_status(pub, lambda s: s["state"] == "online" and s["camera"] == "ok")
    finally:
        runtime.stop()
    last = parse_status(pub.on(edge_status_topic("edge-s"))[-1])
    assert (last.state, last.camera, last.missing) == ("offline", "stopped", list(ROVERS))
    assert all(m.retain and m.qos == 1 for m in pub.messages if m.topic == edge_status_topic("edge-s"))


def test_the_status_stamps_and_rates_come_from_the_runtimes_clock() -> None:
    clock = ManualClock(wall_s=1.8e9)
    source = MemorySource([scene(i) for i in range(3)], clock=clock)
    pub = MemoryPublisher()
    runtime = _runtime(source, ScriptedTracker(), pub, clock).start()
    assert runtime.wait_finished(20.0)
    clock.advance(0.25)
    snapshot = runtime.snapshot()
    status = runtime.current_status()
    runtime.stop()
    assert status.t == 1.8e9 + 0.25
    assert status.fps == runtime.frames_processed / 2.0  # the frames tracked, all within the 2 s window
    assert snapshot.uptime_s == 0.25
    assert [r.last_seen_age_s for r in snapshot.rovers] == [0.25] * 3


def test_poses_are_the_exact_encode_pose_bytes_with_per_rover_seq() -> None:
    source = MemorySource([scene(i) for i in range(5)], realtime=True)
    pub = MemoryPublisher()
    runtime = _runtime(source, ScriptedTracker(), pub).start()
    assert runtime.wait_finished(20.0)
    runtime.stop()
    for k, rover in enumerate(ROVERS):
        payloads = pub.on(pose_topic(rover))
        poses = [parse_pose(p) for p in payloads]
        # Every pose published counts, from 0, whichever frames the tracker got to (a slow one skips some).
        assert [p.seq for p in poses] == list(range(len(poses))) and poses
        assert [p.frame for p in poses] == sorted({p.frame for p in poses})
        for p, pose in zip(payloads, poses, strict=True):
            x_cm = 10.0 * k + pose.frame
            assert p == encode_pose(rover, pose.seq, pose.frame, pose.t, x_cm, 20.0, 0.5, 1.0, None, 0.9)
    assert all(m.qos == 0 and not m.retain for m in pub.messages if m.topic.endswith("/pose"))


@pytest.mark.slow
def test_poses_dropped_while_disconnected_do_not_advance_seq() -> None:
    pub = MemoryPublisher()
    pub.is_connected = False
    source = MemorySource([scene(i) for i in range(30)], loop=True, realtime=True)
    runtime = _runtime(source, ScriptedTracker(), pub).start()
    try:
        assert pub.wait_until(lambda: pub.stats.poses_dropped >= 30, 20.0)
        pub.is_connected = True
        assert pub.wait_until(lambda: len(pub.on(pose_topic("red"))) >= 3, 20.0)
    finally:
        runtime.stop()
    assert [parse_pose(p).seq for p in pub.on(pose_topic("red"))[:3]] == [0, 1, 2]


class ClosingTracker(ScriptedTracker):
    """A tracker with a worker to stop (``edge.pipeline.Pipeline.close``: the edge fits' process)."""

    def __init__(self) -> None:
        super().__init__()
        self.closed = threading.Event()

    def close(self) -> None:
        self.closed.set()


def test_stopping_the_runtime_stops_the_trackers_worker() -> None:
    clock = ManualClock()
    source, tracker, pub = GatedSource(clock), ClosingTracker(), MemoryPublisher()
    runtime = _runtime(source, tracker, pub, clock).start()
    try:
        _wait_status(pub, lambda s: s["state"] == "online")
        assert not tracker.closed.is_set()
    finally:
        runtime.stop()
    assert tracker.closed.is_set()
