"""The edge status (contract v1): online, degraded with the reason, offline on stop; poses as exact encode_pose
bytes. The runtime with the in-memory publisher (STYLE point 3), real threads, scripted sources and trackers."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

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


class GatedSource:
    """Frames at 30 fps while ``flowing`` is set; a read blocks (a stalled camera) while it is clear."""

    def __init__(self) -> None:
        self.flowing = threading.Event()
        self.flowing.set()
        self._inner = MemorySource([scene(i) for i in range(30)], loop=True, realtime=True)

    def open(self) -> SourceInfo:
        return self._inner.open()

    def read(self) -> Frame | None:
        self.flowing.wait()
        return self._inner.read()

    def close(self) -> None:
        self.flowing.set()


def _runtime(source: Any, tracker: Any, publisher: MemoryPublisher) -> EdgeRuntime:
    return EdgeRuntime(
        edge_id="edge-s",
        source=source,
        info=source.open(),
        tracker=tracker,
        publisher=publisher,
        rovers=ROVERS,
        status_interval_s=0.2,
        stall_timeout_s=0.5,
    )


def _wait_status(pub: MemoryPublisher, predicate: Any, timeout_s: float = 20.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for payload in reversed(pub.on(edge_status_topic("edge-s"))):
            status = json.loads(payload)
            if predicate(status):
                return status
        time.sleep(0.05)
    raise AssertionError(f"no status matching; last: {pub.on(edge_status_topic('edge-s'))[-1:]}")


def test_status_follows_rovers_and_camera_and_ends_offline() -> None:
    source, tracker, pub = GatedSource(), ScriptedTracker(), MemoryPublisher()
    runtime = _runtime(source, tracker, pub).start()
    try:
        online = _wait_status(pub, lambda s: s["state"] == "online" and s["camera"] == "ok" and s["fps"] > 10)
        assert online["rovers"] == list(ROVERS) and online["missing"] == []

        tracker.hidden = {"blue"}
        gone = _wait_status(pub, lambda s: s["missing"] == ["blue"])
        assert gone["state"] == "degraded" and gone["rovers"] == ["red", "green"]
        tracker.hidden = set()
        _wait_status(pub, lambda s: s["state"] == "online" and s["missing"] == [])

        source.flowing.clear()  # the camera stalls: a read that never returns
        stalled = _wait_status(pub, lambda s: s["camera"] == "stalled")
        assert stalled["state"] == "degraded"
        source.flowing.set()
        _wait_status(pub, lambda s: s["state"] == "online" and s["camera"] == "ok")
    finally:
        runtime.stop()
    last = parse_status(pub.on(edge_status_topic("edge-s"))[-1])
    assert (last.state, last.camera, last.missing) == ("offline", "stopped", list(ROVERS))
    assert all(m.retain and m.qos == 1 for m in pub.messages if m.topic == edge_status_topic("edge-s"))


def test_poses_are_the_exact_encode_pose_bytes_with_per_rover_seq() -> None:
    source = MemorySource([scene(i) for i in range(5)], realtime=True)  # paced: the tracker gets every frame
    pub = MemoryPublisher()
    runtime = _runtime(source, ScriptedTracker(), pub).start()
    deadline = time.monotonic() + 20
    while not runtime.finished and time.monotonic() < deadline:
        time.sleep(0.02)
    runtime.stop()
    for k, rover in enumerate(ROVERS):
        payloads = pub.on(pose_topic(rover))
        assert [parse_pose(p).seq for p in payloads] == [0, 1, 2, 3, 4]
        for p in payloads:
            pose = parse_pose(p)
            x_cm = 10.0 * k + pose.frame
            assert p == encode_pose(rover, pose.seq, pose.frame, pose.t, x_cm, 20.0, 0.5, 1.0, None, 0.9)
    assert all(m.qos == 0 and not m.retain for m in pub.messages if m.topic.endswith("/pose"))


def test_poses_dropped_while_disconnected_do_not_advance_seq() -> None:
    pub = MemoryPublisher()
    pub.is_connected = False
    source = MemorySource([scene(i) for i in range(30)], loop=True, realtime=True)
    runtime = _runtime(source, ScriptedTracker(), pub).start()
    deadline = time.monotonic() + 20
    while pub.stats.poses_dropped < 30 and time.monotonic() < deadline:
        time.sleep(0.02)
    pub.is_connected = True
    while len(pub.on(pose_topic("red"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    runtime.stop()
    assert pub.stats.poses_dropped >= 30
    assert [parse_pose(p).seq for p in pub.on(pose_topic("red"))[:3]] == [0, 1, 2]
