"""The one rule for publishing a frame's poses (edge.poses), shared by the runtime and the closed loop: a rover's seq
counts only the poses the publisher took; rovers nobody publishes for are skipped; what the contract cannot carry is
reported, not sent."""

from __future__ import annotations

import math

from edge.messages import parse_pose, pose_topic
from edge.poses import publish_poses
from edge.publisher import MemoryPublisher
from edge.tracking import RoverEstimate


def estimate(rover_id: str, x_cm: float = 100.0) -> RoverEstimate:
    return RoverEstimate(rover_id, x_cm, 200.0, 0.5, 1.0, -1.0, 0.9, (640.0, 360.0))


def test_seqs_count_only_what_the_publisher_took_and_unknown_rovers_are_skipped() -> None:
    sink = MemoryPublisher()
    seq = {"red": 0, "blue": 7}
    out = publish_poses(sink, [estimate("red"), estimate("ghost"), estimate("blue")], seq, 12, 1700000000.5)
    assert [rid for rid, _ in out.sent] == ["red", "blue"]
    assert [m.topic for m in sink.messages] == [pose_topic("red"), pose_topic("blue")]
    poses = [parse_pose(m.payload) for m in sink.messages]
    assert [(p.id, p.seq, p.frame, p.t) for p in poses] == [("red", 0, 12, 1700000000.5), ("blue", 7, 12, 1700000000.5)]
    assert seq == {"red": 1, "blue": 8}
    assert [e.rover_id for e in out.seen] == ["red", "blue"] and not out.refused and not out.invalid

    sink.is_connected = False  # the broker is gone: nothing taken, no seq used
    out = publish_poses(sink, [estimate("red")], seq, 13, 1700000000.6)
    assert out.refused == ("red",) and not out.sent and seq["red"] == 1
    sink.is_connected = True
    publish_poses(sink, [estimate("red")], seq, 14, 1700000000.7)
    assert parse_pose(sink.messages[-1].payload).seq == 1  # consecutive across the outage


def test_what_the_contract_cannot_carry_is_reported_not_sent() -> None:
    sink = MemoryPublisher()
    seq = {"red": 0, "green": 0}
    out = publish_poses(sink, [estimate("red", math.nan), estimate("green")], seq, 1, 1700000000.0)
    assert [rid for rid, _ in out.invalid] == ["red"] and "non-finite" in str(out.invalid[0][1])
    assert [rid for rid, _ in out.sent] == ["green"]
    assert seq == {"red": 0, "green": 1}
    assert [e.rover_id for e in out.seen] == ["red", "green"]
