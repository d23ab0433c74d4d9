"""A broker that crashes brings back an older retained formation: no rover drives on it, end to end.

Real parts: Mosquitto with persistence (as ``broker-config`` and Debian set it up), the appliance as ``edge-ips
start`` assembles it (its publisher, its retained stop at every connection, the poses held until that stop is
acknowledged), and each rover's real firmware on its own thread and its own MQTT connection (``edge.sim.fleet``'s
runner, as ``edge-ips sim rovers`` runs it), its motor duties read after every firmware step.

The broker is killed with SIGKILL while a rendezvous is driving and restarted at once: its database holds the line
it saved at its last clean exit. Every rover reconnects, forgets its formation (the contract's rule 2) and is handed
the replayed line; the edge reconnects, publishes its stop, and only then poses again. Every wait is on the rovers'
steps or the edge's publisher, bounded by a generous failure timeout.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from edge.commands import build_formation, send_formation
from edge.config import BrokerTarget
from edge.messages import FORMATION_TOPIC, dumps
from edge.publisher import MqttPublisher
from edge.rover_host import HostRover, firmware_modules
from edge.sim.fleet import RealClock, RoverRunner
from tests.support.appliance import edge_config, running
from tests.support.mosquitto import Mosquitto
from tests.support.proxy import Proxy

pytestmark = [pytest.mark.slow, pytest.mark.realtime]

ROVERS = ["red", "green", "blue"]  # the ids the test scene's rovers carry (DEFAULT_ROVERS)
TIMEOUT_S = 120.0  # failure guard only
OLD_LINE = build_formation("line", ROVERS, seq=41, spacing_cm=60.0)


@dataclass(frozen=True)
class Step:
    """What one firmware step of one rover left behind."""

    t_mono_s: float
    connects: int  # the rover's broker sessions so far
    formation: tuple[str, int] | None  # (kind, seq) applied, None since the last (re)connect
    halt: str
    duties: tuple[int, int]  # left, right PWM duty written to the H-bridge
    own_age_ms: int | None  # age of the rover's own newest pose, as the firmware judges it
    own_seq: int | None  # that pose's seq


class Fleet:
    """The rovers' firmware, each on its own thread against the broker, every step recorded."""

    def __init__(self, broker: Mosquitto) -> None:
        self.changed = threading.Condition()
        self.steps: dict[str, list[Step]] = {r: [] for r in ROVERS}
        self._stop = threading.Event()
        self._rover = firmware_modules()["rover"]
        self.runners = [
            _Watched(self, HostRover({"id": r, "broker": {"host": broker.host}}, broker.host, broker.port), RealClock())
            for r in ROVERS
        ]
        self._threads = [threading.Thread(target=r.run, args=(self._stop,), daemon=True) for r in self.runners]

    def record(self, runner: RoverRunner) -> None:
        fw = runner.rover.rover
        f = fw.formation
        me = fw._me
        known = me >= 0 and fw._ids[me] is not None
        age = int(self._rover.tdiff(fw._last_step, fw._stamp[me])) if known else None
        m = runner.motor_state
        step = Step(
            time.monotonic(),
            int(runner.rover.link.connects) if runner.rover.link is not None else 0,
            None if f is None else (str(f[1]), int(f[0])),
            runner.halt,
            (m.left_duty, m.right_duty),
            age,
            int(fw._seq[me]) if known else None,
        )
        with self.changed:
            self.steps[runner.id].append(step)
            self.changed.notify_all()

    def wait(self, what: str, condition: Callable[[dict[str, list[Step]]], bool]) -> None:
        with self.changed:
            if not self.changed.wait_for(lambda: condition(self.steps), TIMEOUT_S):
                latest = {r: s[-1] if s else None for r, s in self.steps.items()}
                raise AssertionError(f"rovers never {what}: latest steps {latest}")

    def __enter__(self) -> Fleet:
        for thread in self._threads:
            thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(30)
        for runner in self.runners:
            runner.close()


class _Watched(RoverRunner):
    def __init__(self, fleet: Fleet, rover: HostRover, clock: RealClock) -> None:
        super().__init__(rover, clock)
        self.fleet = fleet

    def step(self) -> None:
        super().step()
        self.fleet.record(self)


def every(steps: dict[str, list[Step]], test: Callable[[str, list[Step]], bool]) -> bool:
    return all(test(r, s) for r, s in steps.items())


def driving(step: Step) -> bool:
    return step.duties != (0, 0)


@pytest.fixture
def persistent(tmp_path: Path) -> Iterator[Mosquitto]:
    """A Mosquitto that saves retained messages only at a clean exit (and every 30 min), whose database already
    holds ``OLD_LINE``, as one that ran the fleet on a line before would."""
    (tmp_path / "db").mkdir()
    conf = tmp_path / "persistent.conf"
    conf.write_text(f"listener 1883\nallow_anonymous true\npersistence true\npersistence_location {tmp_path}/db/\n")
    broker = Mosquitto(tmp_path / "run", conf_path=conf)
    with broker:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="earlier-writer")
        client.connect(broker.host, broker.port)
        client.loop_start()
        client.publish(FORMATION_TOPIC, dumps(OLD_LINE), qos=1, retain=True).wait_for_publish(TIMEOUT_S)
        client.loop_stop()
        client.disconnect()
    broker.start()  # the line is on disk now
    try:
        yield broker
    finally:
        broker.stop()


@pytest.mark.parametrize("restart", ["after_the_poses_went_stale", "at_once"])
def test_no_rover_drives_on_the_formation_a_crashed_broker_brings_back(
    persistent: Mosquitto, restart: str, record_property: Callable[[str, object], None]
) -> None:
    """``after_the_poses_went_stale``: the broker is back once every rover's last pose is older than its
    ``stale_ms`` (a broker down for more than 0.4 s): no rover's motors turn from its reconnection until the next
    command. ``at_once``: a rover back within ``stale_ms`` of its last pose still holds that pose, sent before the
    crash; the firmware drives on no pose from before its connection (it drove the replay on it for 3-4 steps, the
    first at full duty, before it learnt that), and the edge sends none after the crash before its stop."""
    broker = persistent
    target = BrokerTarget(embedded=False, host=broker.host, port=broker.port)
    # The edge reaches the broker through a link the test holds down after the crash, until every rover has
    # applied the replayed line: the window this test is about, whatever the reconnection backoffs do.
    link = Proxy(broker.port).start()
    url = f"mqtt://{link.host}:{link.port}"
    config = edge_config(**{"camera.source": "sim", "broker.url": url, "broker.reconnect_max_s": 0.5})
    with running(config) as app, Fleet(broker) as fleet:
        publisher = app.runtime.publisher
        assert isinstance(publisher, MqttPublisher)
        stale_ms = fleet.runners[0].rover.config["control"]["stale_ms"]
        # The stop at start (seq 42, after the line on disk) halts every rover.
        fleet.wait("applied the stop at start", lambda s: every(s, lambda r, st: bool(st) and st[-1].halt == "stop"))

        rendezvous = send_formation(target, lambda seq: build_formation("rendezvous", ROVERS, seq=seq))
        fleet.wait(
            "drove the rendezvous",
            lambda s: every(
                s, lambda r, st: any(x.formation == ("rendezvous", rendezvous.seq) and driving(x) for x in st)
            ),
        )

        assert broker.proc is not None
        link.down()
        broker.proc.kill()  # mid-drive: the rendezvous and the stop before it were never saved
        broker.proc.wait()
        if restart == "after_the_poses_went_stale":
            fleet.wait("saw their poses age", lambda s: every(s, lambda r, st: (st[-1].own_age_ms or 0) > stale_ms))
        broker.start()  # as systemd's Restart=on-failure does; the line comes back from disk
        fleet.wait(
            "reconnected to the replayed line",
            lambda s: every(s, lambda r, st: st[-1].connects >= 2 and st[-1].formation == ("line", OLD_LINE.seq)),
        )
        link.up()

        # Every rover applies the edge's new stop; the edge publishes poses again once it is acknowledged.
        fleet.wait("applied the stop after the crash", lambda s: every(s, lambda r, st: st[-1].halt == "stop"))
        assert publisher.wait_poses_released(TIMEOUT_S)
        after = send_formation(target, lambda seq: build_formation("line", ROVERS, seq=seq, spacing_cm=50.0))
        # Poses flow again: every rover applies the command on fresh poses (one already in its place may stand).
        fleet.wait(
            "applied the command after the crash on fresh poses",
            lambda s: every(s, lambda r, st: any(x.formation == ("line", after.seq) and x.halt == "none" for x in st)),
        )
    link.stop()

    drove: dict[str, list[Step]] = {}
    for rover, steps in fleet.steps.items():
        before = [x for x in steps if x.connects < 2]
        # from the rover's reconnection until it applies the next command
        window = [x for x in steps if x.connects >= 2 and x.formation != ("line", after.seq)]
        assert any(x.formation == ("line", OLD_LINE.seq) for x in window), f"{rover} never saw the replay"
        # until the edge's stop reached it, nothing sent after the crash (the stop comes before any new pose)
        replayed = [x for x in window if x.formation in (None, ("line", OLD_LINE.seq))]
        assert {x.own_seq for x in replayed} == {before[-1].own_seq}, f"{rover} had a pose sent after the crash"
        drove[rover] = [x for x in window if driving(x)]
    record_property("poses_held", publisher.stats.poses_held)
    record_property("steps_driven_on_the_replay", {r: len(d) for r, d in drove.items()})
    record_property(
        "largest_duty_on_the_replay", {r: max((max(x.duties) for x in d), default=0) for r, d in drove.items()}
    )
    assert not any(drove.values()), f"rovers drove between their reconnection and the next command: {drove}"
