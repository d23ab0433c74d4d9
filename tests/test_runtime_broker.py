"""Brokers: the embedded amqtt broker with paho v2 clients, and `broker-config` files enforced by a real Mosquitto."""

from __future__ import annotations

import logging
import socket
import threading
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import paho.mqtt.publish as publish
import pytest

from edge.broker import EmbeddedBroker, acl_text, mosquitto_hash, write_mosquitto_config
from edge.commands import build_formation, send_formation
from edge.config import parse_broker_url
from edge.errors import BrokerError
from edge.messages import (
    FORMATION_TOPIC,
    POSE_WILDCARD,
    ROVER_STATUS_WILDCARD,
    encode_pose,
    parse_formation,
    pose_topic,
    rover_status_topic,
)
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder

ROVERS = ["red", "green", "blue"]
PASSWORDS = {"edge": "edge-pw", "red": "red-pw", "green": "green-pw", "blue": "blue-pw"}


class Client:
    """A paho v2 client (MQTT v5, so the broker tells us when an ACL refuses a publish)."""

    def __init__(self, port: int, user: str | None = None, password: str | None = None) -> None:
        self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="", protocol=mqtt.MQTTv5)
        if user is not None:
            self.c.username_pw_set(user, password)
        self.connected = threading.Event()
        self.reason: Any = None
        self.acks: dict[int, Any] = {}
        self.got: list[mqtt.MQTTMessage] = []
        self._cond = threading.Condition()
        self.c.on_connect = self._on_connect
        self.c.on_publish = self._on_publish
        self.c.on_message = self._on_message
        self.c.connect("127.0.0.1", port)
        self.c.loop_start()
        self.connected.wait(10)

    def _on_connect(self, c: Any, u: Any, flags: Any, rc: Any, props: Any) -> None:
        self.reason = rc
        self.connected.set()

    def _on_publish(self, c: Any, u: Any, mid: int, rc: Any, props: Any) -> None:
        with self._cond:
            self.acks[mid] = rc
            self._cond.notify_all()

    def _on_message(self, c: Any, u: Any, msg: mqtt.MQTTMessage) -> None:
        with self._cond:
            self.got.append(msg)
            self._cond.notify_all()

    @property
    def accepted(self) -> bool:
        return self.reason is not None and not self.reason.is_failure

    def publish(self, topic: str, payload: bytes, retain: bool = False) -> Any:
        """The broker's PUBACK reason code for a QoS 1 publish."""
        info = self.c.publish(topic, payload, qos=1, retain=retain)
        with self._cond:
            self._cond.wait_for(lambda: info.mid in self.acks, timeout=10)
            return self.acks[info.mid]

    def subscribe(self, topic: str) -> None:
        done = threading.Event()
        self.c.on_subscribe = lambda *a: done.set()
        self.c.subscribe(topic, qos=1)
        done.wait(10)

    def wait_for(self, topic: str, timeout_s: float = 10.0) -> list[bytes]:
        with self._cond:
            self._cond.wait_for(lambda: any(m.topic == topic for m in self.got), timeout=timeout_s)
            return [bytes(m.payload) for m in self.got if m.topic == topic]

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


# -- embedded broker ---------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_embedded_broker_serves_paho_v2_clients_with_retained_messages_and_last_will() -> None:
    with EmbeddedBroker("127.0.0.1", 0) as broker:
        port = broker.port
        with MqttRecorder("127.0.0.1", port, topics=[POSE_WILDCARD, "edge/will"]) as sub:
            assert sub.wait_subscribed(10)
            pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="dying")
            pub.will_set("edge/will", b"offline", qos=1, retain=True)
            pub.connect("127.0.0.1", port, keepalive=2)
            pub.loop_start()
            payload = encode_pose("red", 0, 1, 1.0, 1.0, 2.0, None, None, None, 1.0)
            pub.publish(pose_topic("red"), payload, qos=0)
            pub.publish(FORMATION_TOPIC, b"retained!", qos=1, retain=True).wait_for_publish(5)
            assert sub.wait_for(lambda m: any(x.payload == payload for x in m), 10)
            pub.loop_stop()
            pub.socket().close()  # vanish without DISCONNECT: the broker publishes the will
            assert sub.wait_for(lambda m: any(x.topic == "edge/will" for x in m), 20)
            # amqtt 0.12.1 alone would also push edge/will here (another session's subscription): see _make_broker
            with MqttRecorder("127.0.0.1", port, topics=[FORMATION_TOPIC]) as late:
                assert late.wait_subscribed(10)
                # a marker after the retained message: whatever the broker would push at subscription came before it
                publish.single(FORMATION_TOPIC, b"marker", hostname="127.0.0.1", port=port)
                assert late.wait_for(lambda m: any(x.payload == b"marker" for x in m), 10)
        got = [(m.topic, m.payload, m.retain) for m in late.messages]
        assert got == [(FORMATION_TOPIC, b"retained!", True), (FORMATION_TOPIC, b"marker", False)]


def test_embedded_broker_says_when_the_port_is_taken() -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        with pytest.raises(BrokerError, match=rf"port {port} on 127.0.0.1 is already in use.*embedded_port"):
            EmbeddedBroker("127.0.0.1", port).start()


def test_embedded_broker_refuses_a_second_start_and_is_quiet_about_qos0_drops_on_shutdown(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with EmbeddedBroker("127.0.0.1", 0) as broker:
        with pytest.raises(BrokerError, match="already running"):
            broker.start()
        amqtt_log = logging.getLogger("amqtt.broker")
        with caplog.at_level(logging.WARNING):
            amqtt_log.warning("3 messages not broadcasted")  # what amqtt says when it stops with poses queued
            amqtt_log.warning("something else went wrong")
    assert [r.getMessage() for r in caplog.records if r.name == "amqtt.broker"] == ["something else went wrong"]


@pytest.mark.slow
@pytest.mark.parametrize("broker_kind", ["mosquitto", "embedded"])
def test_retained_formation_reaches_a_late_subscriber_and_seq_follows(tmp_path: Path, broker_kind: str) -> None:
    if broker_kind == "mosquitto":
        server: Any = Mosquitto(tmp_path).start()
        url = server.url
    else:
        server = EmbeddedBroker("127.0.0.1", 0).start()
        url = f"mqtt://127.0.0.1:{server.port}"
    try:
        target = parse_broker_url(url)
        first = send_formation(target, lambda seq: build_formation("line", ROVERS, seq=seq, spacing_cm=60.0))
        second = send_formation(target, lambda seq: build_formation("triangle", ROVERS, seq=seq, side_cm=100.0))
        assert (first.seq, second.seq) == (1, 2)
        with MqttRecorder("127.0.0.1", target.port, topics=[FORMATION_TOPIC]) as late:
            assert late.wait_for(lambda m: len(m) >= 1, 10)
        seen = parse_formation(late.messages[0].payload)
        assert late.messages[0].retain and (seen.kind, seen.seq, seen.side) == ("triangle", 2, 100.0)
    finally:
        server.stop()


# -- broker-config with a real Mosquitto -------------------------------------------------------------------------
@pytest.fixture
def deployed(tmp_path: Path) -> Any:
    """A real Mosquitto with broker-config's files; :attr:`port` is the local listener (the edge's)."""
    files = write_mosquitto_config(tmp_path / "conf", rovers=ROVERS, edge_id="edge-1", passwords=PASSWORDS)
    with Mosquitto(tmp_path / "run", conf_path=files.conf) as broker:
        yield broker


@pytest.mark.slow
def test_broker_config_rover_cannot_publish_poses_or_other_rovers_status(deployed: Mosquitto) -> None:
    edge = Client(deployed.port, "edge", PASSWORDS["edge"])
    red = Client(deployed.ports[1883], "red", PASSWORDS["red"])  # rovers log in on the network listener
    green = Client(deployed.ports[1883], "green", PASSWORDS["green"])
    try:
        assert edge.accepted and red.accepted and green.accepted
        green.subscribe(POSE_WILDCARD)
        edge.subscribe(ROVER_STATUS_WILDCARD)
        pose = encode_pose("red", 0, 1, 1.0, 10.0, 20.0, None, None, None, 1.0)

        forged = encode_pose("blue", 0, 1, 1.0, 0.0, 0.0, None, None, None, 1.0)
        assert red.publish(pose_topic("blue"), forged).value == 0x87  # Not authorized
        assert red.publish(rover_status_topic("green"), b'{"state":"offline"}').value == 0x87
        assert red.publish(FORMATION_TOPIC, b"{}").value == 0x87

        assert not edge.publish(pose_topic("red"), pose).is_failure
        assert not red.publish(rover_status_topic("red"), b'{"state":"online"}').is_failure
        assert green.wait_for(pose_topic("red")) == [pose]
        assert edge.wait_for(rover_status_topic("red")) == [b'{"state":"online"}']
        # those two went out after the forged ones were refused: anything forged would have arrived before them
        assert green.wait_for(pose_topic("blue"), timeout_s=0) == [], "a forged pose got through"
        assert edge.wait_for(rover_status_topic("green"), timeout_s=0) == [], "a forged status got through"
    finally:
        for c in (edge, red, green):
            c.close()


@pytest.mark.slow
def test_broker_config_rover_reads_the_retained_formation(deployed: Mosquitto) -> None:
    target = parse_broker_url(f"mqtt://edge:{PASSWORDS['edge']}@127.0.0.1:{deployed.port}")
    send_formation(target, lambda seq: build_formation("rendezvous", ROVERS, seq=seq))
    blue = Client(deployed.ports[1883], "blue", PASSWORDS["blue"])
    try:
        blue.subscribe(FORMATION_TOPIC)
        assert parse_formation(blue.wait_for(FORMATION_TOPIC)[0]).kind == "rendezvous"
    finally:
        blue.close()


@pytest.mark.slow
@pytest.mark.parametrize(("user", "password"), [("red", "wrong"), ("edge", "red-pw"), ("nobody", "x"), (None, None)])
def test_broker_config_refuses_wrong_passwords_and_anonymous(
    deployed: Mosquitto, user: str | None, password: str | None
) -> None:
    client = Client(deployed.port, user, password)
    try:
        assert client.reason is not None and client.reason.is_failure
    finally:
        client.close()


def test_broker_config_writes_secret_files_and_refuses_to_overwrite(tmp_path: Path) -> None:
    files = write_mosquitto_config(tmp_path, rovers=ROVERS, install_dir=Path("/etc/mosquitto/edge-ips"))
    assert files.credentials.stat().st_mode & 0o777 == 0o600
    assert files.passwd.stat().st_mode & 0o777 == 0o600
    conf = files.conf.read_text()
    assert "allow_anonymous false" in conf and "password_file /etc/mosquitto/edge-ips/passwd" in conf
    assert "set_tcp_nodelay true" in conf and "max_packet_size 2048" in conf and "message_size_limit 512" in conf
    local, network = conf.split("listener 1884 127.0.0.1")[1].split("listener 1883 0.0.0.0")
    assert "use_username_as_clientid" not in local and "use_username_as_clientid true" in network
    creds = files.credentials.read_text()
    assert creds.count("password = ") == 5  # edge, viewer, three rovers
    with pytest.raises(BrokerError, match="already exist"):
        write_mosquitto_config(tmp_path, rovers=ROVERS)


@pytest.mark.parametrize(
    ("rovers", "edge_user", "message"),
    [(["red", "red"], "edge", "red named more than once"), (["red"], "red", "must differ"), (["Red"], "edge", "'Red'")],
)
def test_broker_config_refuses_bad_names(tmp_path: Path, rovers: list[str], edge_user: str, message: str) -> None:
    with pytest.raises(BrokerError, match=message):
        write_mosquitto_config(tmp_path, rovers=rovers, edge_user=edge_user)


def test_acl_lists_each_rover_once_with_its_own_status_topic() -> None:
    text = acl_text("edge", "edge-1", ["red", "green"])
    assert text.count("topic write ips/v2/rovers/red/status") == 1
    assert "topic write ips/v1/rovers/+/pose" in text.split("user red")[0]  # only the edge writes poses


def test_python_hash_is_what_mosquitto_passwd_writes() -> None:
    h = mosquitto_hash("abc", salt=b"\x59\x23\xc7\x23\x41\x6e\x50\x28\x6a\x0a\x5a\x32")
    # the same salt and password through mosquitto_passwd 2.0.11 on this machine:
    assert h == (
        "$7$101$WSPHI0FuUChqCloy$6FGW/hxWEeSNW2t6ed/dZrcGaSLfQbL3HQneIaikbCoa40+eWtfIEvkheFrzoR+2Rttj18jSDZrzkj0OJ3ktPg=="
    )
    assert free_port() > 0
