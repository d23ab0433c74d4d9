"""The MQTT publisher against a real Mosquitto: exact pose bytes at QoS 0, retained status, last will, no backlog."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from edge.config import parse_broker_url
from edge.errors import BrokerError
from edge.messages import StatusV1, edge_status_topic, encode_pose, parse_pose, parse_status, pose_topic
from edge.publisher import ConnectionHold, MemoryPublisher, MqttPublisher
from tests.support.mosquitto import Mosquitto
from tests.support.runtime import MqttRecorder, poses

ROVERS = ("red", "green", "blue")


def _publisher(broker: Mosquitto, **kw: object) -> MqttPublisher:
    return MqttPublisher(
        parse_broker_url(broker.url), edge_id="edge-t", rovers=ROVERS, reconnect_min_s=0.1, reconnect_max_s=0.5, **kw
    )  # type: ignore[arg-type]


def _status(state: str = "online") -> StatusV1:
    return StatusV1(v=1, edge="edge-t", state=state, camera="ok", fps=30.0, rovers=list(ROVERS), missing=[], t=1.0)  # type: ignore[arg-type]


def _pose(rover: str, seq: int, frame: int) -> bytes:
    return encode_pose(rover, seq, frame, 1_800_000_000.0 + frame / 30, 100.0 + frame, 50.0, 0.5, 1.0, -1.0, 0.9)


@pytest.mark.slow
def test_poses_go_out_at_qos0_on_their_own_topic_with_the_exact_bytes(mosquitto: Mosquitto) -> None:
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec:
        pub = _publisher(mosquitto)
        pub.start()
        assert pub.wait_connected(10)
        assert rec.wait_subscribed(10)
        sent = {r: _pose(r, 0, 7) for r in ROVERS}
        for rover, payload in sent.items():
            assert pub.publish_pose(rover, payload)
        assert rec.wait_for(lambda m: len(poses(m)) >= 3, 10)
        pub.stop()
    got = {m.topic: m for m in poses(rec.messages)}
    for rover, payload in sent.items():
        message = got[pose_topic(rover)]
        assert message.payload == payload
        assert message.qos == 0 and not message.retain
        assert parse_pose(message.payload).id == rover
    assert pub.stats.poses_sent == 3 and pub.stats.poses_dropped == 0


@pytest.mark.slow
def test_status_is_retained_and_republished_after_a_broker_restart(mosquitto: Mosquitto) -> None:
    reconnected = threading.Event()

    def on_connected(hold: ConnectionHold) -> None:
        if hold.number >= 2:
            reconnected.set()

    pub = _publisher(mosquitto, on_connected=on_connected)
    pub.start()
    assert pub.wait_connected(10)
    assert pub.publish_status(_status())
    mosquitto.restart()  # persistence off: the retained status is gone with the old broker
    assert reconnected.wait(15)
    assert pub.stats.connects == 2 and pub.stats.disconnects == 1
    # The republished status may still be on its way: once one subscriber has it, the broker holds it retained.
    with MqttRecorder("127.0.0.1", mosquitto.port, topics=[edge_status_topic("edge-t")]) as arrived:
        assert arrived.wait_for(lambda m: len(m) >= 1, 10)
    with MqttRecorder("127.0.0.1", mosquitto.port, topics=[edge_status_topic("edge-t")]) as late:
        assert late.wait_for(lambda m: len(m) >= 1, 10)
    pub.stop()
    first = late.messages[0]
    assert first.retain and parse_status(first.payload).state == "online"


@pytest.mark.slow
def test_poses_are_dropped_while_disconnected_and_never_sent_later(mosquitto: Mosquitto) -> None:
    pub = _publisher(mosquitto)
    pub.start()
    assert pub.wait_connected(10)
    mosquitto.stop()
    assert pub.wait_disconnected(10)
    assert not pub.connected
    stale = [_pose("red", i, 1000 + i) for i in range(20)]
    assert not any(pub.publish_pose("red", p) for p in stale)
    assert pub.stats.poses_dropped == 20 and pub.stats.dropped_by_rover == {"red": 20}
    mosquitto.start()
    with MqttRecorder("127.0.0.1", mosquitto.port) as rec:
        assert pub.wait_connected(15)
        assert rec.wait_subscribed(10)
        fresh, marker = _pose("red", 20, 5000), _pose("red", 21, 5001)
        pub.publish_pose("red", fresh)
        pub.publish_pose("red", marker)  # anything still queued from before would arrive ahead of it
        assert rec.wait_for(lambda m: any(p.payload == marker for p in poses(m)), 10)
    pub.stop()
    assert [m.payload for m in poses(rec.messages)] == [fresh, marker]


@pytest.mark.slow
def test_wrong_credentials_are_a_clear_error(tmp_path: Path) -> None:
    with Mosquitto(tmp_path, users={"edge": "right"}) as broker:
        target = parse_broker_url(f"mqtt://edge:wrong@127.0.0.1:{broker.port}")
        pub = MqttPublisher(target, edge_id="edge-t", rovers=ROVERS)
        pub.start()
        with pytest.raises(BrokerError, match=r"refused the connection: .*(authori[sz]ed|password).*broker.username"):
            pub.wait_connected(10)
        pub.stop()


LAST_WILL_CHILD = """
import signal, sys
from edge.config import parse_broker_url
from edge.messages import StatusV1
from edge.publisher import MqttPublisher
pub = MqttPublisher(parse_broker_url(sys.argv[1]), edge_id="edge-w", rovers=["red"], keepalive_s=2)
pub.start()
assert pub.wait_connected(10)
pub.publish_status(StatusV1(v=1, edge="edge-w", state="online", camera="ok", fps=30.0, rovers=["red"], t=1.0))
print("online", flush=True)
signal.pause()  # until killed
"""


@pytest.mark.slow
def test_the_last_will_says_offline_when_the_edge_dies(mosquitto: Mosquitto) -> None:
    child = subprocess.Popen([sys.executable, "-c", LAST_WILL_CHILD, mosquitto.url], stdout=subprocess.PIPE)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == b"online"
        with MqttRecorder("127.0.0.1", mosquitto.port, topics=[edge_status_topic("edge-w")]) as rec:
            assert rec.wait_for(lambda m: any(json.loads(x.payload)["state"] == "online" for x in m), 10)
            child.send_signal(signal.SIGKILL)  # no clean disconnect: the broker must publish the will
            assert rec.wait_for(lambda m: json.loads(m[-1].payload)["state"] == "offline", 20)
    finally:
        child.kill()
        child.wait()
    will = parse_status(rec.messages[-1].payload)
    assert (will.state, will.camera, will.missing) == ("offline", "stopped", ["red"])


def test_memory_publisher_drops_when_switched_off() -> None:
    pub = MemoryPublisher()
    assert pub.publish_pose("red", b"{}")
    pub.is_connected = False
    assert not pub.publish_pose("red", b"{}")
    assert pub.on(pose_topic("red")) == [b"{}"]
    assert (pub.stats.poses_sent, pub.stats.poses_dropped) == (1, 1)


@pytest.mark.slow
def test_publisher_sets_tcp_nodelay(mosquitto: Mosquitto) -> None:
    import socket

    pub = _publisher(mosquitto)
    pub.start()
    assert pub.wait_connected(10)
    sock = pub._client.socket()
    assert sock is not None and sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 1
    pub.stop()


@pytest.mark.slow
def test_tls_broker_with_the_right_ca_gets_poses_and_a_wrong_ca_is_refused(tmp_path: Path) -> None:
    from edge.commands import build_formation, send_formation
    from edge.config import BrokerTarget
    from edge.mqttclient import TlsFiles
    from tests.support.runtime import make_tls_files

    good = make_tls_files(tmp_path / "good")
    other = make_tls_files(tmp_path / "other", name="other-ca")
    conf = tmp_path / "tls.conf"
    conf.write_text(
        "allow_anonymous true\npersistence false\n"
        f"cafile {good['ca']}\ncertfile {good['cert']}\nkeyfile {good['key']}\n"
    )
    with Mosquitto(tmp_path / "run", conf_path=conf) as broker:
        target = BrokerTarget(embedded=False, host="localhost", port=broker.port, tls=True)
        pub = MqttPublisher(target, edge_id="edge-t", rovers=ROVERS, tls=TlsFiles(ca_file=good["ca"]))
        pub.start()
        assert pub.wait_connected(10)
        pub.stop()
        with pytest.raises(BrokerError, match="certificate verify failed"):
            send_formation(target, lambda seq: build_formation("stop", ["red"], seq=seq), tls=TlsFiles(other["ca"]))
