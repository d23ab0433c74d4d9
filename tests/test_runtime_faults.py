"""Faults against real parts: a Mosquitto restarted mid-run, an MJPEG stream that stalls and then vanishes."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from edge.publisher import MqttPublisher
from edge.runtime import EdgeRuntime
from tests.support.appliance import edge_config, running
from tests.support.mosquitto import Mosquitto
from tests.support.runtime import MjpegServer, MqttRecorder, poses, statuses

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # end to end, or long: left out of the quick loop (-m 'not slow')


def _frame_by_frame(runtime: EdgeRuntime, condition: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    """Wait until ``condition()`` holds, checking it each time the tracker finishes a frame."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        runtime.wait_tracked(1.0)
    return True


@contextmanager
def _logged(logger: str, text: str, times: int) -> Iterator[threading.Event]:
    """An event set once ``logger`` has logged a message containing ``text`` ``times`` times."""
    done = threading.Event()
    seen = [0]

    class Counter(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if text in record.getMessage():
                seen[0] += 1
                if seen[0] >= times:
                    done.set()

    target = logging.getLogger(logger)
    handler, level = Counter(), target.level
    target.addHandler(handler)
    target.setLevel(logging.INFO)
    try:
        yield done
    finally:
        target.removeHandler(handler)
        target.setLevel(level)


def test_broker_restart_mid_run_reconnects_republishes_status_and_sends_no_stale_poses(mosquitto: Mosquitto) -> None:
    config = edge_config(**{"broker.url": mosquitto.url})
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec, running(config) as app:
        publisher = app.runtime.publisher
        assert isinstance(publisher, MqttPublisher)
        assert rec.wait_for(lambda m: len(poses(m)) >= 30)
        before = [json.loads(m.payload) for m in poses(rec.messages)]

        mosquitto.stop()
        t_down = time.time()
        # frames keep coming while the broker is away: a second's worth of poses, dropped
        assert _frame_by_frame(app.runtime, lambda: publisher.stats.poses_dropped >= 90)
        dropped_while_down = publisher.stats.poses_dropped
        mosquitto.start()
        t_back, t_back_mono = time.time(), time.monotonic()
        n_before = len(rec.messages)

        assert rec.wait_for(lambda m: len(poses(m[n_before:])) >= 30, 30), "poses did not resume"
        assert publisher.stats.connects == 2 and publisher.stats.disconnects == 1  # one reconnect, to the new broker
        # (how long a reconnect takes is a figure, not a bar: benchmarks/bench_reconnect.py)
        reconnect_s = publisher.stats.connected_since_mono - t_back_mono  # type: ignore[operator]
        assert dropped_while_down > 0
        assert not app.runtime.finished and app.runtime.error is None

        after = [json.loads(m.payload) for m in poses(rec.messages[n_before:])]
        t_connected = t_back + reconnect_s
        # No backlog: of the poses sent after the reconnect, at most the frame in the tracker's hands when the
        # connection came back (one per rover) was captured before it; nothing captured during the outage.
        early = [p for p in after if p["t"] < t_connected]
        assert len(early) <= 3 and len({p["id"] for p in early}) == len(early), f"backlog after reconnect: {early}"
        outage = [p for p in before + after if t_down + 0.1 < p["t"] < t_back - 0.1]
        assert not outage, f"poses captured while the broker was down were sent: {outage[:3]}"
        for rover in ("red", "green", "blue"):
            seq_before = [p["seq"] for p in before if p["id"] == rover]
            seq_after = [p["seq"] for p in after if p["id"] == rover]
            # seq counts messages handed to the broker: it goes on where it was (those sent into the dying
            # connection are lost, as QoS 0 allows), with no gap after the reconnect
            assert seq_after == list(range(seq_after[0], seq_after[0] + len(seq_after)))
            assert seq_before[-1] < seq_after[0]
        fresh_status = [s for s in statuses(rec.messages[n_before:]) if s["t"] >= t_back - 0.1]
        assert fresh_status and fresh_status[0]["state"] in ("online", "degraded")

    with MqttRecorder("127.0.0.1", mosquitto.port, topics=["ips/v1/edge/+/status"]) as late:
        assert late.wait_for(lambda m: len(m) >= 1, 10)
    assert json.loads(late.messages[-1].payload)["state"] == "offline"  # clean stop after the restart


def _state_seen(rec: MqttRecorder, start: int, predicate: object) -> bool:
    return rec.wait_for(lambda m: any(predicate(s) for s in statuses(m[start:])), 30)  # type: ignore[operator]


def test_stalled_then_vanished_stream_degrades_reopens_with_backoff_and_tracking_resumes(mosquitto: Mosquitto) -> None:
    server = MjpegServer(fps=30).start()
    config = edge_config(**{"broker.url": mosquitto.url, "camera.source": server.url})
    try:
        with MqttRecorder("127.0.0.1", mosquitto.port) as rec, running(config) as app:
            assert rec.wait_for(lambda m: len(poses(m)) >= 20)
            assert _state_seen(rec, 0, lambda s: s["state"] == "online" and s["camera"] == "ok")

            # 1. the stream stalls: connection open, no frames
            server.stalled.set()
            n = len(rec.messages)
            assert _state_seen(rec, n, lambda s: s["state"] == "degraded" and s["camera"] in ("stalled", "missing"))
            server.stalled.clear()
            t_resume = time.time()
            n = len(rec.messages)
            assert rec.wait_for(lambda m: len([p for p in poses(m[n:]) if json.loads(p.payload)["t"] > t_resume]) >= 20)
            assert _state_seen(rec, n, lambda s: s["state"] == "online")
            failures_after_stall = app.runtime.capture.failures
            assert failures_after_stall >= 1 and app.runtime.capture.reopens >= 1

            # 2. the camera vanishes: connection refused until it comes back on the same address
            port = int(server.url.split(":")[2].split("/")[0])
            with _logged("edge.sources", "reopen failed", times=2) as failed_twice:
                server.stop()
                n = len(rec.messages)
                assert _state_seen(rec, n, lambda s: s["state"] == "degraded" and s["camera"] == "missing")
                assert failed_twice.wait(30)  # the backoff has tried and failed at least twice
            server = MjpegServer(fps=30, port=port).start()
            t_back = time.time()
            n = len(rec.messages)
            assert rec.wait_for(lambda m: len([p for p in poses(m[n:]) if json.loads(p.payload)["t"] > t_back]) >= 20)
            assert _state_seen(rec, n, lambda s: s["state"] == "online" and s["camera"] == "ok")
            assert app.runtime.capture.failures > failures_after_stall
            frames = [json.loads(p.payload)["frame"] for p in poses(rec.messages) if b'"red"' in p.payload]
            assert frames == sorted(frames), "frame numbers keep increasing across reopens"
    finally:
        server.stop()
