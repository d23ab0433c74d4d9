"""The edge's side of formation commands, against a real Mosquitto: seq wraps instead of overflowing, a foreign or
hostile retained message never stops a command (the dashboard's 502), and the appliance halts the fleet at start."""

from __future__ import annotations

import json
import logging
import signal
import threading
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from edge.commands import StopAtStart, build_formation, send_formation
from edge.config import BrokerTarget
from edge.dashboard.formation import FormationDesk
from edge.messages import FORMATION_TOPIC, MAX_INT, dumps, encode_pose, next_seq
from edge.publisher import MqttPublisher
from tests.support.appliance import edge_config, running
from tests.support.dashboard import FormationSubscriber
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder

TOKEN = "s3cret-token"


def target(broker: Mosquitto) -> BrokerTarget:
    return BrokerTarget(embedded=False, host=broker.host, port=broker.port)


def retain(broker: Mosquitto, payload: bytes) -> None:
    """Leave ``payload`` retained on the formation topic, as anyone on an open broker could."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="hostile")
    client.connect(broker.host, broker.port)
    client.loop_start()
    client.publish(FORMATION_TOPIC, payload, qos=1, retain=True).wait_for_publish(10)
    client.loop_stop()
    client.disconnect()


def retained(broker: Mosquitto) -> dict[str, object]:
    sub = FormationSubscriber(broker.host, broker.port)
    try:
        doc, was_retained = sub.next()
        assert was_retained
        return doc
    finally:
        sub.close()


LINE = dumps(build_formation("line", ["red", "green", "blue"], seq=41, spacing_cm=60.0))
HOSTILE = dumps(build_formation("line", ["red", "green", "blue"], seq=MAX_INT, spacing_cm=60.0))


@pytest.mark.parametrize(("seq", "after"), [(None, 1), (0, 1), (1, 2), (41, 42), (MAX_INT - 1, MAX_INT), (MAX_INT, 1)])
def test_seq_counts_up_and_wraps_to_one(seq: int | None, after: int) -> None:
    assert next_seq(seq) == after


@pytest.mark.slow
@pytest.mark.parametrize(
    ("what", "payload", "seq", "warned"),
    [
        ("nothing retained", None, 1, False),
        ("a line", LINE, 42, False),
        ("a hostile seq at the top of the range", HOSTILE, 1, False),
        ("a cleared retained message", b"", 1, False),
        ("not JSON", b"drive!", 1, True),
        ("another version", b'{"v":2,"seq":5,"kind":"line","ids":[]}', 1, True),
        ("oversized", b'{"v":1,"seq":5,"kind":"stop","ids":[]' + b" " * 2000 + b"}", 1, True),
    ],
)
def test_a_command_follows_whatever_is_retained_and_never_fails_because_of_it(
    mosquitto: Mosquitto, caplog: pytest.LogCaptureFixture, what: str, payload: bytes | None, seq: int, warned: bool
) -> None:
    if payload is not None:
        retain(mosquitto, payload)
    with caplog.at_level(logging.WARNING, logger="edge.publisher"):
        sent = send_formation(target(mosquitto), lambda s: build_formation("stop", [], seq=s))
    assert sent.seq == seq, what
    assert retained(mosquitto) == json.loads(dumps(sent))
    assert any("ignoring the retained formation" in r.getMessage() for r in caplog.records) == warned, what


@pytest.mark.slow
def test_the_dashboards_stop_is_published_after_a_hostile_retained_seq(mosquitto: Mosquitto) -> None:
    retain(mosquitto, HOSTILE)
    desk = FormationDesk(target(mosquitto), edge_id="edge-t", rover_ids=["red", "green", "blue"], token=TOKEN)
    status, body = desk.command({"Authorization": f"Bearer {TOKEN}"}, b'{"kind":"stop","ids":[]}')
    assert status == 200, body
    assert body["seq"] == 1 and body["formation"]["kind"] == "stop"
    assert retained(mosquitto)["kind"] == "stop"


def halted_on_connect(broker: Mosquitto) -> tuple[MqttPublisher, StopAtStart]:
    """The appliance's wiring: the edge's publisher, and the stop at start run by its first connection."""
    stop = StopAtStart(target(broker), client_id="edge-t-stop")
    publisher = MqttPublisher(
        target(broker), edge_id="edge-t", rovers=["red"], on_connected=stop.on_connected, reconnect_max_s=0.5
    )
    publisher.start()
    return publisher, stop


@pytest.mark.slow
@pytest.mark.parametrize(("before", "seq"), [(None, 1), (LINE, 42), (HOSTILE, 1), (b"junk", 1)])
def test_the_stop_at_start_follows_whatever_is_retained(mosquitto: Mosquitto, before: bytes | None, seq: int) -> None:
    if before is not None:
        retain(mosquitto, before)
    publisher, stop = halted_on_connect(mosquitto)
    try:
        assert stop.done.wait(30)
        assert retained(mosquitto) == json.loads(dumps(build_formation("stop", [], seq=seq)))
    finally:
        publisher.stop()


@pytest.mark.slow
def test_a_broker_that_comes_up_later_gets_the_stop_on_the_first_connection(tmp_path: Path) -> None:
    broker = Mosquitto(tmp_path / "late", port=free_port())
    publisher, stop = halted_on_connect(broker)
    try:
        assert not publisher.wait_connected(0.5) and not stop.done.is_set()
        with broker:
            assert stop.done.wait(30)
            assert retained(broker)["kind"] == "stop"
    finally:
        publisher.stop()


@pytest.mark.slow
def test_a_broker_that_crashes_and_brings_back_an_older_formation_gets_a_stop_again(tmp_path: Path) -> None:
    # Mosquitto saves its retained messages on a clean exit (and every 30 min): after a crash it brings back the
    # line the stop had replaced, and the rovers, which reconnect, would apply it.
    (tmp_path / "db").mkdir()
    conf = tmp_path / "persistent.conf"
    conf.write_text(f"listener 1883\nallow_anonymous true\npersistence true\npersistence_location {tmp_path}/db/\n")
    broker = Mosquitto(tmp_path / "run", conf_path=conf)
    with broker:
        retain(broker, LINE)  # saved at the clean exit
    broker.start()
    publisher, stop = halted_on_connect(broker)
    try:
        assert stop.done.wait(30) and retained(broker)["kind"] == "stop"
        assert broker.proc is not None
        broker.proc.kill()  # a crash: the stop was never saved
        broker.proc.wait()
        broker.start()
        sub = FormationSubscriber(broker.host, broker.port)
        try:
            seen = [sub.next()[0]]  # the replayed line, or already the edge's new stop
            while seen[-1]["kind"] != "stop":
                seen.append(sub.next()[0])
        finally:
            sub.close()
        assert [d["kind"] for d in seen] in (["stop"], ["line", "stop"])
        assert retained(broker)["kind"] == "stop" and publisher.stats.connects == 2
    finally:
        publisher.stop()
        broker.stop()


@pytest.mark.slow
def test_the_appliance_publishes_a_retained_stop_when_it_starts(mosquitto: Mosquitto) -> None:
    retain(mosquitto, LINE)  # what the fleet was doing before the edge restarted
    sub = FormationSubscriber(mosquitto.host, mosquitto.port)
    config = edge_config(**{"camera.source": "sim", "broker.url": mosquitto.url})
    try:
        with running(config):
            seen = [sub.next()[0]]  # the line, retained
            while seen[-1]["kind"] != "stop":
                seen.append(sub.next()[0])
    finally:
        sub.close()
    assert [(d["kind"], d["seq"]) for d in seen] == [("line", 41), ("stop", 42)]
    assert retained(mosquitto) == seen[-1]


class Said(logging.Handler):
    """An event set when a log record says ``text``."""

    def __init__(self, text: str) -> None:
        super().__init__(logging.WARNING)
        self.text = text
        self.event = threading.Event()

    def emit(self, record: logging.LogRecord) -> None:
        if self.text in record.getMessage():
            self.event.set()

    def wait(self, timeout_s: float) -> bool:
        return self.event.wait(timeout_s)


@pytest.mark.slow
def test_poses_wait_for_the_stop_and_a_stop_the_broker_refuses_keeps_them_held_and_is_tried_again(
    tmp_path: Path,
) -> None:
    # An ACL that does not (yet) let the edge's login write formations: the broker acknowledges and drops the stop.
    acl = "user edge\ntopic write ips/v1/rovers/+/pose\ntopic readwrite ips/v1/edge/#\ntopic read ips/v1/formation\n"
    admin = "user admin\ntopic readwrite #\n"
    broker = Mosquitto(tmp_path / "acl", users={"edge": "edge-pw", "admin": "admin-pw"}, acl=admin + acl).start()
    login = BrokerTarget(embedded=False, host=broker.host, port=broker.port, username="edge", password="edge-pw")
    stop = StopAtStart(login, client_id="edge-t-stop", retry_min_s=0.05, retry_max_s=0.2)
    publisher = MqttPublisher(login, edge_id="edge-t", rovers=["red"], on_connected=stop.on_connected, hold_poses=True)
    watch = MqttRecorder(
        broker.host,
        broker.port,
        topics=(FORMATION_TOPIC, "ips/v1/rovers/+/pose"),
        username="admin",
        password="admin-pw",
    )
    pose = encode_pose("red", 1, 1, 1.7e9, 10.0, 20.0, None, None, None, 1.0)
    refused = Said("the retained stop was not published")
    logging.getLogger("edge.commands").addHandler(refused)
    try:
        watch.start()
        assert watch.wait_subscribed()
        publisher.start()
        assert publisher.wait_connected(30)
        assert not publisher.publish_pose("red", pose)  # held: no stop taken for this connection
        assert publisher.stats.poses_held == 1 and publisher.stats.poses_dropped == 0
        assert refused.wait(60) and not stop.done.is_set()

        assert broker.proc is not None
        (broker.workdir / "acl").write_text(admin + acl + "topic write ips/v1/formation\n")
        broker.proc.send_signal(signal.SIGHUP)  # Mosquitto reloads its ACL; the next attempt goes through
        assert publisher.wait_poses_released(60)
        assert stop.done.is_set() and stop.attempts >= 2
        assert publisher.publish_pose("red", pose)
        assert watch.wait_for(lambda m: any(x.topic.endswith("/pose") for x in m), 30)
    finally:
        logging.getLogger("edge.commands").removeHandler(refused)
        publisher.stop()
        watch.stop()
        broker.stop()
    kinds = [("pose" if m.topic.endswith("/pose") else json.loads(m.payload)["kind"]) for m in watch.messages]
    assert kinds == ["stop", "pose"]  # nothing before the stop, and the stop before the first pose
