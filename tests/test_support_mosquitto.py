"""The private-broker fixture really brokers messages and enforces its users."""

from __future__ import annotations

import threading
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from tests.support.mosquitto import Mosquitto

pytestmark = pytest.mark.slow  # end to end, or long: left out of the quick loop (-m 'not slow')


def _connect(port: int, user: str | None = None, password: str | None = None) -> tuple[mqtt.Client, int]:
    done = threading.Event()
    result: list[int] = []
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="")
    if user is not None:
        client.username_pw_set(user, password)

    def on_connect(c, u, flags, reason_code, props):  # type: ignore[no-untyped-def]
        result.append(reason_code.value)
        done.set()

    client.on_connect = on_connect
    client.connect("127.0.0.1", port)
    client.loop_start()
    done.wait(5)
    return client, result[0] if result else -1


def test_private_broker_round_trips_a_message(mosquitto: Mosquitto) -> None:
    got, subscribed = threading.Event(), threading.Event()
    sub, rc = _connect(mosquitto.port)
    assert rc == 0
    sub.on_message = lambda c, u, m: got.set() if m.payload == b"hello" else None
    sub.on_subscribe = lambda *args: subscribed.set()
    sub.subscribe("t/x", qos=1)
    assert subscribed.wait(10)  # the broker acknowledged: from now on nothing published on t/x is missed
    pub, _ = _connect(mosquitto.port)
    pub.publish("t/x", b"hello", qos=1).wait_for_publish(10)
    delivered = got.wait(10)
    for c in (sub, pub):
        c.loop_stop()
        c.disconnect()
    assert delivered


def test_private_broker_refuses_a_wrong_password(tmp_path: Path) -> None:
    with Mosquitto(tmp_path, users={"edge": "s3cret"}) as broker:
        good, rc_good = _connect(broker.port, "edge", "s3cret")
        bad, rc_bad = _connect(broker.port, "edge", "wrong")
        for c in (good, bad):
            c.loop_stop()
    assert rc_good == 0
    assert rc_bad != 0
