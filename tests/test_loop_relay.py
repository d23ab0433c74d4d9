"""A rover's Wi-Fi hop in the closed loop (edge.sim.relay): the real firmware (HostRover) behind a LinkRelay, a real
broker (the embedded amqtt, and Mosquitto), the simulated clock stepped by hand. What the firmware receives, when,
in what order; a long outage that costs the association: the firmware drops its connection, halts, reconnects,
gets the retained formation again and drives on; its status crosses upstream."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from edge.commands import build_formation
from edge.config import BrokerTarget
from edge.messages import FORMATION_TOPIC, dumps, encode_pose, pose_topic, rover_status_topic
from edge.publisher import MqttPublisher
from edge.rover_host import HostRover
from edge.sim.link import LinkSettings
from edge.sim.loop import SimClock
from edge.sim.loop_fleet import Fleet, LoopBroker
from edge.sim.relay import split_packets
from edge.sim.rover import rover_config
from tests.support.mosquitto import Mosquitto


@dataclass
class Rig:
    """One rover (red) behind its link, a publisher standing in for the edge, a clock stepped by hand."""

    fleet: Fleet
    publisher: MqttPublisher
    broker: BrokerTarget
    clock: SimClock
    seq: int = 0

    def publish_own_pose(self, x_cm: float = 150.0, y_cm: float = 200.0) -> None:
        t = 1.7e9 + self.clock.now_s  # captured now by the edge's clock: the rover dates poses by it
        payload = encode_pose("red", self.seq, self.seq, t, x_cm, y_cm, 0.0, 0.0, 0.0, 1.0)
        assert self.publisher.publish_pose("red", payload)
        self.seq += 1
        self.fleet.await_poses({pose_topic("red"): payload}, timeout_s=5.0)

    def step_to(self, t_ms: int) -> None:
        self.clock.now_us = t_ms * 1000
        self.fleet.step(t_ms)

    @property
    def rover(self) -> HostRover:
        return self.fleet.rovers["red"]

    def retained(self, topic: str) -> dict[str, object]:
        """The broker's retained message on ``topic``, read by a new subscriber."""
        got: list[bytes] = []
        arrived = threading.Event()
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="read-retained")

        def on_message(c: mqtt.Client, userdata: object, message: mqtt.MQTTMessage) -> None:
            got.append(message.payload)
            arrived.set()

        client.on_message = on_message
        client.connect(self.broker.host, self.broker.port)
        client.subscribe(topic, qos=1)
        client.loop_start()
        try:
            assert arrived.wait(10.0), f"nothing retained on {topic}"
        finally:
            client.loop_stop()
            client.disconnect()
        return dict(json.loads(got[0]))


@contextmanager
def rig_with(broker_url: str | None, link: str) -> Iterator[Rig]:
    broker = LoopBroker(broker_url)
    publisher = MqttPublisher(broker.target, edge_id="t", rovers=("red", "green"), client_id="edge-t")
    clock = SimClock()
    fleet = None
    try:
        publisher.start()
        assert publisher.wait_connected(10.0)
        formation = build_formation("rendezvous", ("red", "green"), seq=1)
        assert publisher.publish(FORMATION_TOPIC, dumps(formation), qos=1, retain=True)
        fleet = Fleet([rover_config("red")], broker.target, LinkSettings.parse(link), 0, lambda: clock.now_s)
        fleet.join(formation.seq)
        yield Rig(fleet, publisher, broker.target, clock)
    finally:
        if fleet is not None:
            fleet.close()
        publisher.stop()
        broker.close()


def test_mqtt_packets_are_split_whole_whatever_the_chunks() -> None:
    packets = [b"\x30\x03\x00\x01a", b"\xc0\x00", b"\x30" + bytes([0x80, 0x01]) + b"\x00\x01t" + b"x" * 125]
    stream = b"".join(packets)
    for cut in range(1, len(stream)):
        buf = bytearray()
        got = []
        for chunk in (stream[:cut], stream[cut:]):
            buf += chunk
            got += split_packets(buf)
        assert got == packets and not buf


def test_a_pose_reaches_the_firmware_when_the_link_says_and_not_before() -> None:
    with rig_with(None, "latency=50ms") as rig:  # every frame 50 ms on the air, nothing lost
        rig.step_to(20)
        rig.clock.now_us = 100_000
        rig.publish_own_pose()  # at the relay now (await_poses), due at 150 ms
        rig.step_to(120)
        rig.step_to(140)
        assert rig.rover.last_seq("red") is None  # at the relay, not yet through the air
        rig.step_to(160)
        assert rig.rover.last_seq("red") == 0
        assert rig.fleet.fresh_ms["red"] == [160]
        assert rig.fleet.relays["red"].log.pose_delays_s == [pytest.approx(0.05)]


@pytest.mark.slow
def test_a_long_outage_drops_the_connection_and_the_rover_rejoins_with_the_retained_formation() -> None:
    # outages of 2 s, ten a minute; the station loses its access point 0.5 s into one, back 0.3 s after it ends
    link = "latency=5ms,outages=10/min,outage=2s,drop=0.5s,rejoin=0.3s"
    with rig_with(None, link) as rig:
        model = rig.fleet.models["red"]
        outage = model.outages(600.0)[0]
        assert outage.dropped
        end_ms = int(1000 * outage.rejoin_at_s) + 3000
        halts: dict[int, str] = {}
        for t_ms in range(20, end_ms, 20):
            rig.clock.now_us = t_ms * 1000
            if t_ms % 40 == 0:
                rig.publish_own_pose(150.0 + 0.01 * (t_ms % 1000), 200.0)
            rig.step_to(t_ms)
            halts[t_ms] = rig.rover.halt
        log = rig.fleet.relays["red"].log
        drop_ms = 1000 * (outage.start_s + 0.5)
        rejoin_ms = 1000 * outage.rejoin_at_s
        # driving before the outage, halted without Wi-Fi, driving again after it
        assert halts[int(drop_ms // 20 * 20) - 200] in ("none", "probe")
        off = [h for t, h in halts.items() if drop_ms + 20 < t < rejoin_ms]
        assert off and all(h == "disconnected" for h in off)
        assert halts[max(halts)] in ("none", "probe")
        assert log.connections == 2  # a new connection after it
        assert [c[FORMATION_TOPIC] for c in log.delivered] == [1, 1]  # the retained formation, on each connection
        assert log.poses_lost > 0  # sent while it was gone: nowhere to go
        assert rig.rover.rover.formation is not None
        # fresh poses again, and its status crossed upstream on the new connection: the broker's retained status
        # is no longer the last will it published when the old connection was taken over
        assert rig.fleet.fresh_ms["red"][-1] > rejoin_ms
        status = rig.retained(rover_status_topic("red"))
        assert status["state"] == "online" and status["halt"] in ("none", "probe")


@pytest.mark.slow
def test_the_relay_works_with_mosquitto_too(tmp_path: Path) -> None:
    with Mosquitto(tmp_path / "mosquitto") as broker, rig_with(broker.url, "typical,outages=0") as rig:
        for t_ms in range(20, 2000, 20):
            rig.clock.now_us = t_ms * 1000
            if t_ms % 40 == 0:
                rig.publish_own_pose()
            rig.step_to(t_ms)
        seqs = rig.fleet.fresh_ms["red"]
        assert len(seqs) > 30  # most of the 49 poses, each the newest when read
        assert rig.rover.last_seq("red") is not None and rig.rover.last_seq("red") >= rig.seq - 5
