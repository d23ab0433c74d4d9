"""End to end with a real Mosquitto: the edge publishes poses (paho-mqtt, ``edge.messages.encode_pose``), and the
firmware's link.py, rover.py and main.py run under CPython with stand-ins for ``machine`` and ``network`` only.

The firmware's clock here is the host's real one (``time.monotonic``), since messages travel in real time; the
assertions are about what the firmware decided at which of its own clock readings, never about wall-clock limits.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest

from edge import messages
from edge.config import BrokerTarget
from edge.publisher import MqttPublisher
from edge.rover_host import HostRover, firmware_modules
from firmware.harness.runner import rover_configs
from tests.support.mosquitto import Mosquitto

pytestmark = pytest.mark.realtime

fw = firmware_modules()
fm: Any = fw["formation"]
motors_mod: Any = fw["motors"]
app: Any = fw["app"]

WORLD = {"red": (120.0, 100.0, 0.3), "green": (250.0, 320.0, 2.0), "blue": (330.0, 90.0, -1.0)}
FORMATION = {"v": 1, "seq": 1, "kind": "triangle", "ids": ["red", "green", "blue"], "side": 100.0}


def now_ms() -> int:
    return int(time.monotonic() * 1000) & ((1 << 30) - 1)


class EdgePublisher:
    """The edge's side, with the edge's own publisher (edge.publisher.MqttPublisher): every rover's pose at 30 Hz
    from a static world, and the retained formation."""

    def __init__(self, broker: Mosquitto, world: dict[str, tuple[float, float, float]] = WORLD) -> None:
        self.world = world
        target = BrokerTarget(embedded=False, host=broker.host, port=broker.port)
        self.publisher = MqttPublisher(target, edge_id="edge-test", rovers=list(world))
        self.publisher.start()
        assert self.publisher.wait_connected(10)
        self.seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def formation(self, doc: dict[str, Any]) -> None:
        assert self.publisher.publish(messages.FORMATION_TOPIC, json.dumps(doc).encode(), qos=1, retain=True)

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            for rid, (x, y, theta) in self.world.items():
                payload = messages.encode_pose(rid, self.seq, self.seq, time.time(), x, y, theta, None, None, 1.0)
                self.publisher.publish_pose(rid, payload)
            self.seq += 1
            self._stop.wait(1 / 30)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def close(self) -> None:
        self.stop()
        self.publisher.stop()


@pytest.fixture
def edge(mosquitto: Mosquitto) -> Iterator[EdgePublisher]:
    pub = EdgePublisher(mosquitto)
    pub.formation(FORMATION)
    yield pub
    pub.close()


def loop_once(rover: HostRover) -> int:
    """One turn of the firmware's own loop (``app.loop``: a step, then the rest of ``period_ms``, as on the chip);
    returns the firmware time of the step."""
    app.loop(rover.rover, None, steps=1)
    return int(rover.rover._last_step)


def step_until(rover: HostRover, done: Callable[[], bool], limit_s: float = 10.0) -> int:
    """Run the firmware's loop until done(); returns the firmware time of that step (``limit_s``: a failure guard)."""
    deadline = time.monotonic() + limit_s
    while True:
        t = loop_once(rover)
        if done():
            return t
        assert time.monotonic() < deadline, f"gave up waiting; halt={rover.halt}, log={rover.log_lines[-5:]}"


def expected_command(
    cfg: dict[str, Any], world: dict[str, tuple[float, float, float]], theta: float, spread: float
) -> list[float]:
    """What the law gives for red in this static world with heading estimate ``theta`` (``spread``), computed from
    formation.py directly."""
    ids = FORMATION["ids"]
    bx, by = [0.0] * 3, [0.0] * 3
    fm.offsets(fm._TRIANGLE, 3, 0.0, FORMATION["side"], 0.0, bx, by)
    px = [world[r][0] for r in ids]
    py = [world[r][1] for r in ids]
    cx, cy = [0.0] * 3, [0.0] * 3
    fm.orient(fm._TRIANGLE, None, px, py, bx, by, 3, cx, cy)
    law = fw["rover"].make_law(cfg)
    others = [r for r in world if r != "red"]
    out = [0.0] * 6
    law.command(
        0,
        px,
        py,
        cx,
        cy,
        3,
        None,
        None,
        [world[r][0] for r in others],
        [world[r][1] for r in others],
        2,
        theta,
        spread,
        out,
    )
    return out


@pytest.mark.slow
def test_motor_commands_are_the_ones_the_law_computes(mosquitto: Mosquitto, edge: EdgePublisher) -> None:
    edge.start()
    rover = HostRover(rover_configs(["red"])[0], mosquitto.host, mosquitto.port)
    me = lambda: rover.rover._me  # noqa: E731
    checked = 0
    # Steps in which red's own pose arrived: the command is the law's for the poses and the heading estimate, which
    # the pose's heading has just pulled to itself (fused with the commanded turn since the last pose).
    step_until(rover, lambda: rover.halt == "none" and all(rover.last_seq(r) is not None for r in WORLD))
    while checked < 10:
        seq = rover.rover._seq[me()] if me() >= 0 else None
        loop_once(rover)
        if me() >= 0 and rover.rover._seq[me()] != seq:  # its own pose arrived in this step
            heading = rover.rover.heading
            # The pose's heading was fused, not set aside as an outlier; how far odometry carried the estimate
            # since the last pose depends on the wall time between steps (a loaded machine steps less often).
            assert heading.rejected == 0
            assert abs(fm.wrap(heading.theta - WORLD["red"][2])) < heading.gate
            want = expected_command(rover.config, WORLD, heading.theta, heading.spread)
            assert rover.rover.command == pytest.approx(want, abs=1e-9)
            m = rover.config["motors"]
            duty_l = motors_mod.duty_for_speed(want[4], m["max_wheel_rad_s"], m["deadband_duty"], m["min_wheel_rad_s"])
            duty_r = motors_mod.duty_for_speed(want[5], m["max_wheel_rad_s"], m["deadband_duty"], m["min_wheel_rad_s"])
            left, right = rover.motors.left, rover.motors.right  # what the firmware wrote through machine.PWM/Pin
            assert (left.pwm.duty_value, right.pwm.duty_value) == (duty_l, duty_r)
            assert left.dir.level == (1 if (want[4] >= 0) != m["left"]["invert"] else 0)
            assert right.dir.level == (1 if (want[5] >= 0) != m["right"]["invert"] else 0)
            checked += 1
    assert rover.rover.rejected == 0
    rover.close()


@pytest.mark.slow
def test_motors_stop_within_half_a_second_of_the_last_pose_when_the_publisher_stops(
    mosquitto: Mosquitto, edge: EdgePublisher
) -> None:
    edge.start()
    rover = HostRover(rover_configs(["red"])[0], mosquitto.host, mosquitto.port)
    step_until(rover, lambda: rover.halt == "none")
    edge.stop()
    times: list[tuple[int, int, bool]] = []  # (firmware time, own pose's age stamp, motors running)

    def record() -> bool:  # until the stale halt (the fade may bring the duties to 0 a little before it)
        r = rover.rover
        state = rover.motor_state
        times.append((r._last_step, r._stamp[r._me], state.left_duty > 0 or state.right_duty > 0))
        return rover.halt == "stale"

    t_stop = step_until(rover, record)
    last_rx = times[-1][1]
    story = f"halt={rover.halt}, steps (t, rx, running)={times[-8:]}, log={rover.log_lines[-4:]}"
    assert not times[-1][2], story
    stale_ms = rover.config["control"]["stale_ms"]
    assert stale_ms + rover.config["control"]["period_ms"] <= 500  # the flashed default meets the 0.5 s bar
    assert stale_ms < t_stop - last_rx <= 500, story  # not before stale_ms, and within half a second
    running_after = [t - rx for t, rx, running in times if running and rx == last_rx]
    assert all(age <= stale_ms for age in running_after), story  # cut at the first step after stale_ms
    rover.close()


@pytest.mark.slow
def test_broker_restart_is_survived_with_a_fresh_subscription(mosquitto: Mosquitto, edge: EdgePublisher) -> None:
    edge.start()
    rover = HostRover(rover_configs(["red"])[0], mosquitto.host, mosquitto.port)
    step_until(rover, lambda: rover.halt == "none")
    assert rover.link is not None
    mosquitto.stop()
    step_until(rover, lambda: rover.halt == "disconnected")
    assert rover.motor_state.left_duty == 0 and rover.motor_state.right_duty == 0
    mosquitto.start()  # same port, no memory of the old session, its subscriptions or the retained formation
    seq_before = rover.last_seq("green")
    step_until(rover, lambda: rover.connected and rover.last_seq("green") != seq_before, limit_s=20)
    assert rover.halt == "idle" and rover.rover.formation is None  # the broker holds no formation: none applied
    edge.formation(FORMATION)
    step_until(rover, lambda: rover.halt == "none")  # poses flow again: resubscribed on the new session
    assert rover.link.connects == 2 and rover.link.drops == 1
    rover.close()


class Seen(list[dict[str, Any]]):
    """Statuses as a subscriber receives them (paho's thread appends), and a wait for a condition on them."""

    def __init__(self) -> None:
        super().__init__()
        self._changed = threading.Condition()

    def add(self, status: dict[str, Any]) -> None:
        with self._changed:
            self.append(status)
            self._changed.notify_all()

    def wait_for(self, cond: Callable[[], bool], limit_s: float = 10.0) -> None:
        """Until ``cond()`` holds after a status arrived (``limit_s``: a failure guard)."""
        with self._changed:
            assert self._changed.wait_for(cond, limit_s), f"condition not met; statuses: {self[-3:]}"


def _status_listener(broker: Mosquitto, rover_id: str) -> tuple[mqtt.Client, Seen]:
    seen = Seen()
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"watch-{rover_id}")
    client.on_message = lambda c, u, m: seen.add({**json.loads(m.payload), "_retain": m.retain})
    client.connect(broker.host, broker.port)
    client.subscribe(messages.rover_status_topic(rover_id), qos=1)
    client.loop_start()
    return client, seen


@pytest.mark.slow
def test_status_is_published_and_the_last_will_says_offline(mosquitto: Mosquitto, edge: EdgePublisher) -> None:
    edge.start()
    watch, seen = _status_listener(mosquitto, "red")
    rover = HostRover(rover_configs(["red"])[0], mosquitto.host, mosquitto.port)
    step_until(rover, lambda: any(s["halt"] == "none" for s in seen))
    online = [s for s in seen if s["state"] == "online"]
    assert online and all(s["id"] == "red" and s["v"] == 2 and s["fw"] == fw["rover"].VERSION for s in online)
    assert (online[-1]["formation"], online[-1]["seq"]) == ("triangle", 1)
    assert online[-1]["_retain"] is False  # live, so not flagged retained
    rover.crash()  # TCP gone without DISCONNECT, like a rover losing power
    seen.wait_for(lambda: seen[-1]["state"] == "offline")
    assert seen[-1] == {
        "v": 2,
        "id": "red",
        "state": "offline",
        "halt": "disconnected",
        "formation": None,
        "seq": None,
        "fw": None,
        "_retain": False,
    }
    # A client arriving later gets the retained will.
    late, late_seen = _status_listener(mosquitto, "red")
    late_seen.wait_for(lambda: bool(late_seen))
    assert late_seen[0]["state"] == "offline" and late_seen[0]["_retain"]
    for c in (watch, late):
        c.loop_stop()
        c.disconnect()


@pytest.mark.slow
def test_the_rover_works_under_an_acl_that_lets_it_publish_only_its_status(tmp_path: Path) -> None:
    acl = (
        "user edge\ntopic write ips/v1/rovers/+/pose\ntopic write ips/v1/formation\n\n"
        "user red\ntopic read ips/v1/rovers/+/pose\ntopic read ips/v1/formation\n"
        "topic write ips/v2/rovers/red/status\n\n"
        "user watcher\ntopic read ips/v1/#\ntopic read ips/v2/#\n"
    )
    users = {"edge": "e-pass", "red": "r-pass", "watcher": "w-pass"}
    with Mosquitto(tmp_path / "acl-broker", users=users, acl=acl) as broker:
        pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="edge")
        pub.username_pw_set("edge", "e-pass")
        pub.connect(broker.host, broker.port)
        pub.loop_start()
        pub.publish(messages.FORMATION_TOPIC, json.dumps(FORMATION), qos=1, retain=True).wait_for_publish()
        watcher = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="watcher")
        watcher.username_pw_set("watcher", "w-pass")
        seen = Seen()
        watcher.on_message = lambda c, u, m: seen.add(json.loads(m.payload))
        watcher.connect(broker.host, broker.port)
        watcher.subscribe(messages.rover_status_topic("red"), qos=1)
        watcher.loop_start()
        cfg = rover_configs(["red"])[0]
        cfg["broker"] = {**cfg["broker"], "user": "red", "password": "r-pass"}
        rover = HostRover(cfg, broker.host, broker.port)
        seq = 0

        def publish_and_check() -> bool:
            nonlocal seq
            for rid, (x, y, theta) in WORLD.items():
                pub.publish(
                    messages.pose_topic(rid),
                    messages.encode_pose(rid, seq, seq, time.time(), x, y, theta, None, None, 1.0),
                )
            seq += 1
            return rover.halt == "none" and any(s["halt"] == "none" for s in seen)

        step_until(rover, publish_and_check)
        rover.close()
        seen.wait_for(lambda: seen[-1]["state"] == "offline")  # the clean goodbye, through the same ACL
        for c in (pub, watcher):
            c.loop_stop()
            c.disconnect()


@pytest.mark.slow
def test_losing_wifi_stops_the_motors_and_the_link_comes_back(mosquitto: Mosquitto, edge: EdgePublisher) -> None:
    edge.start()
    cfg = rover_configs(["red"])[0]
    cfg["wifi"] = {"ssid": "lab", "password": "secret"}
    rover = HostRover(cfg, mosquitto.host, mosquitto.port)
    step_until(rover, lambda: rover.halt == "none")
    assert rover.link is not None
    rover.link.wlan.drop()
    rover.step(now_ms())
    assert rover.halt == "disconnected" and rover.motor_state.left_duty == 0
    step_until(rover, lambda: rover.halt == "none", limit_s=30)  # the link re-joins the network, then the broker
    assert rover.link.wlan.connect_calls >= 1 and rover.link.connects == 2
    rover.close()


@pytest.mark.slow
def test_main_runs_the_board_loop_under_cpython(mosquitto: Mosquitto, edge: EdgePublisher, tmp_path: Path) -> None:
    edge.start()
    cfg = rover_configs(["red"])[0]
    cfg["broker"] = {**cfg["broker"], "host": mosquitto.host, "port": mosquitto.port}
    path = tmp_path / "config.json"
    path.write_text(json.dumps(cfg))
    watch, seen = _status_listener(mosquitto, "red")

    r = app.run(str(path), steps=100)  # two seconds of the real loop, watchdog and all
    assert r.steps == 100 and r.received > 100
    assert any(s["halt"] == "none" for s in seen)  # it drove
    seen.wait_for(lambda: seen[-1]["state"] == "offline")  # and said goodbye when the loop ended
    assert r.motors.left.duty == 0 and r.motors.right.duty == 0
    watch.loop_stop()
    watch.disconnect()
