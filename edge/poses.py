"""Tracker estimates to pose messages: the one rule for publishing a frame's poses (the runtime and the simulator).

For each estimate of a rover the edge publishes for: encode it as a pose v1 message (``edge.messages.encode_pose``)
with the rover's next ``seq``, hand it to the publisher, and count the seq only when the publisher took it, so a
rover sees consecutive seqs across a broker outage. What the contract cannot carry (a NaN, a coordinate out of
range) is not sent and is reported.
"""

from __future__ import annotations

from collections.abc import Iterable, MutableMapping
from dataclasses import dataclass
from typing import Protocol

from edge.errors import MessageError
from edge.messages import encode_pose
from edge.tracking import RoverEstimate


class PoseSink(Protocol):
    """What takes a rover's pose message: ``edge.publisher.MqttPublisher`` and the in-memory publisher."""

    def publish_pose(self, rover_id: str, payload: bytes) -> bool: ...


@dataclass(frozen=True)
class PosesOut:
    """What became of one frame's estimates."""

    sent: tuple[tuple[str, bytes], ...]  # (rover id, payload) the publisher took, in order
    refused: tuple[str, ...]  # rovers whose pose the publisher did not take (disconnected): seq not used
    invalid: tuple[tuple[str, MessageError], ...]  # rovers whose estimate the contract cannot carry
    seen: tuple[RoverEstimate, ...]  # the estimates of rovers in ``seq``, sent or not


def publish_poses(
    sink: PoseSink,
    estimates: Iterable[RoverEstimate],
    seq: MutableMapping[str, int],
    frame_index: int,
    t_capture_s: float,
) -> PosesOut:
    """Publish one frame's poses. ``seq``: the next seq of every rover published for (estimates of other rovers
    are skipped: nobody subscribed for them); advanced for each pose the sink took."""
    sent: list[tuple[str, bytes]] = []
    refused: list[str] = []
    invalid: list[tuple[str, MessageError]] = []
    seen: list[RoverEstimate] = []
    for est in estimates:
        rid = est.rover_id
        if rid not in seq:
            continue
        seen.append(est)
        try:
            payload = encode_pose(
                rid,
                seq[rid],
                frame_index,
                t_capture_s,
                est.x_cm,
                est.y_cm,
                est.theta_rad,
                est.vx_cm_s,
                est.vy_cm_s,
                est.quality,
            )
        except MessageError as exc:
            invalid.append((rid, exc))
            continue
        if sink.publish_pose(rid, payload):
            sent.append((rid, payload))
            seq[rid] += 1
        else:
            refused.append(rid)
    return PosesOut(tuple(sent), tuple(refused), tuple(invalid), tuple(seen))
