"""The fusion service's network thread on a real Mosquitto: a burst of boards' frames is fused before the clocks
learn from it, and every frame is learned."""

from __future__ import annotations

import logging
import select
import threading
import time
from dataclasses import replace

import paho.mqtt.client as mqtt
import pytest

from edge.board_messages import detections_topic
from edge.config import parse_broker_url
from edge.fusion.core import FusedPose
from edge.fusion.detections import Detections, encode_detections
from edge.fusion.lease import LEASE_TOPIC
from edge.fusion.service import FuserService
from tests.support.fusion import Board, circle, record
from tests.support.mosquitto import Mosquitto


@pytest.mark.slow
def test_a_burst_of_frames_is_fused_before_the_clocks_learn_and_every_frame_is_learned(mosquitto: Mosquitto) -> None:
    """Four frames published together (two boards, two instants): the first is held until the next is in the
    fuser's socket, so its learning must wait for the burst; all four are learned in the end."""
    boards = [Board("a", (0, 0, 400, 400)), Board("b", (0, 0, 400, 400), phase_s=0.013)]
    rec = record(boards, {"r1": circle((200, 200), 80, 30)}, 1.0)
    now = time.time()
    burst = [
        replace(d, t_capture_s=now + d.t_capture_s - 0.5, t_sent_s=now + d.t_capture_s - 0.49)
        for k in (10, 11)
        for d in (rec.frames["a"][k], rec.frames["b"][k])
    ]
    service = FuserService(parse_broker_url(mosquitto.url), "f1")
    fuser = service.fuser
    add, learn = fuser.add, fuser.learn_pending
    learned: list[int] = []
    all_learned = threading.Event()

    def held_add(d: Detections, now_s: float | None = None, learn: bool = True) -> list[FusedPose]:
        if not learned and not fuser.unlearned:  # the burst's first frame: wait until the next one is here
            sock = service._client.socket()
            assert sock is not None and select.select([sock], [], [], 10.0)[0], "the burst's second frame never came"
        return add(d, now_s=now_s, learn=learn)

    def counted_learn() -> None:
        learned.append(len(fuser.unlearned))
        learn()
        if sum(learned) == len(burst):
            all_learned.set()

    fuser.add = held_add  # type: ignore[method-assign]
    fuser.learn_pending = counted_learn  # type: ignore[method-assign]
    subscribed = threading.Event()
    fuse = service._fuse

    def fuse_seen(payload: bytes) -> None:
        subscribed.set()
        fuse(payload)

    service._fuse = fuse_seen  # type: ignore[method-assign]
    board = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="board")
    board.connect("127.0.0.1", mosquitto.port)
    board.loop_start()
    try:
        # a retained message the fuser refuses, delivered when its subscription takes effect: then the burst
        board.publish(detections_topic("probe"), b"{}", qos=1, retain=True).wait_for_publish(10.0)
        service.start()
        assert subscribed.wait(10.0), "the fuser never subscribed"
        infos = [board.publish(detections_topic(d.edge_id), encode_detections(d), qos=1) for d in burst]
        for info in infos:
            info.wait_for_publish(10.0)
        assert all_learned.wait(10.0), f"learned {learned} of {len(burst)} frames"
    finally:
        board.disconnect()
        board.loop_stop()
        service.stop()
    assert learned[0] >= 2  # the first frame's learning waited for the frame behind it
    assert sum(learned) == len(burst) and set(fuser.aligner.estimates()) == {"a", "b"}
    assert service.stats.detections == len(burst) and service.stats.invalid == 1


def test_a_malformed_lease_message_is_refused_in_one_line(caplog: pytest.LogCaptureFixture) -> None:
    service = FuserService(parse_broker_url("mqtt://127.0.0.1:1"), "f1")  # never started: no broker needed
    message = mqtt.MQTTMessage(topic=LEASE_TOPIC.encode())
    message.payload = b'{"not": "a lease"}'
    with caplog.at_level(logging.WARNING, logger="edge.fusion"):
        service._on_message(service._client, None, message)
    assert service.stats.invalid == 1
    (line,) = [r.getMessage() for r in caplog.records if "refused a message" in r.getMessage()]
    assert f"refused a message on {LEASE_TOPIC} (1 so far): " in line and "\n" not in line
