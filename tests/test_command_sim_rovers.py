"""``edge-ips sim rovers`` and its library (``edge.sim.fleet``): one-line errors for every user mistake, each rover
with its own credentials behind a real ACL, two writers at once, and the per-rover runner a live twin steps on its
own clock."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from edge.broker import EmbeddedBroker, write_mosquitto_config
from edge.cli import main
from edge.commands import build_formation, send_formation
from edge.config import BrokerTarget
from edge.messages import FORMATION_TOPIC, ROVER_STATUS_WILDCARD, dumps, encode_pose, pose_topic
from edge.rover_host import HostRover, check_rover_config
from edge.sim.fleet import FleetEvent, RoverRunner, SimFleet, fleet_configs, rover_broker, start_fleet
from tests.support.command import retained_now
from tests.support.mosquitto import Mosquitto, free_port
from tests.support.runtime import MqttRecorder

IDS = ["red", "green", "blue"]
PASSWORDS = {"edge": "edge-pw", "red": "red-pw", "green": "green-pw", "blue": "blue-pw"}


def sim_rovers(*args: str) -> Any:
    return CliRunner().invoke(main, ["sim", "rovers", *args])


def _bundle(directory: Path, rover_id: str, **broker: Any) -> None:
    (directory / rover_id).mkdir(parents=True)
    config = {"id": rover_id, "broker": {"host": "192.168.1.50", "user": rover_id, **broker}}
    (directory / rover_id / "config.json").write_text(json.dumps(config))


@pytest.mark.parametrize(
    ("what", "args", "files", "error"),
    [
        ("not a broker URL", ["--broker", "http://x"], {}, "--broker: 'http://x' is not a broker URL"),
        ("the edge's word for its own broker", ["--broker", "embedded"], {}, "give the broker's address"),
        ("TLS", ["--broker", "mqtts://127.0.0.1"], {}, "rovers speak plain MQTT"),
        ("shared credentials", ["--broker", "mqtt://u:p@127.0.0.1"], {}, "each rover uses its own"),
        ("no such directory", ["--config-dir", "{tmp}/nope"], {}, "nope: no such directory"),
        ("an empty directory", ["--config-dir", "{tmp}/empty"], {"empty/": ""}, "no rover configs"),
        ("a rover without config", ["--config-dir", "{tmp}/b", "--ids", "red,pink"], {"b/red": ""}, "'pink'"),
        ("another rover's config", ["--config-dir", "{tmp}/c"], {"c/red.json": '{"id":"blue"}'}, "not 'red'"),
        ("not JSON", ["--config-dir", "{tmp}/d"], {"d/red.json": "{id:"}, "red.json: not JSON"),
        (
            "a bad value",
            ["--config-dir", "{tmp}/e"],
            {"e/red.json": '{"id":"red","control":{"period_ms":1}}'},
            "period_ms",
        ),
        ("bad ids", ["--ids", "Red,"], {}, "--ids: rover id 'Red' is not an id"),
        ("an id twice", ["--ids", "red,red"], {}, "--ids: red named more than once"),
        ("credentials not TOML", ["--credentials", "{tmp}/c.toml"], {"c.toml": "[rovers"}, "not a broker credentials"),
        ("an empty login", ["--credentials", "{tmp}/c.toml"], {"c.toml": "[edge]\n"}, "[edge]: username and password"),
        (
            "no rover in them",
            ["--credentials", "{tmp}/c.toml"],
            {"c.toml": '[edge]\nusername = "edge"\npassword = "secret"\n'},
            "no [rovers.red] credentials",
        ),
        (
            "a rover missing",
            ["--credentials", "{tmp}/c.toml"],
            {"c.toml": '[edge]\nusername = "edge"\npassword = "e"\n[rovers.red]\nusername = "red"\npassword = "x"\n'},
            "green",
        ),
        ("nothing listening", ["--broker", "mqtt://127.0.0.1:{port}"], {}, "cannot reach broker"),
    ],
)
def test_every_mistake_is_one_line_and_exit_2(
    tmp_path: Path, what: str, args: list[str], files: dict[str, str], error: str
) -> None:
    for name, text in files.items():
        if name.endswith("/"):
            (tmp_path / name).mkdir()
        elif "." not in name:  # a bundle directory
            _bundle(tmp_path / name.split("/")[0], name.split("/")[1])
        else:
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name).write_text(text)
    given = [a.format(tmp=tmp_path, port=free_port()) for a in args]
    if "--broker" not in given:
        given = ["--broker", f"mqtt://127.0.0.1:{free_port()}", *given]
    result = sim_rovers(*given)
    assert result.exit_code == 2, (what, result.output)
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and error in lines[0], (what, result.output)
    assert "Traceback" not in result.output


@pytest.fixture
def acl_broker(tmp_path: Path) -> Iterator[tuple[Mosquitto, Path]]:
    """A Mosquitto with the users and ACL of ``edge-ips broker-config``; its credentials.toml."""
    files = write_mosquitto_config(tmp_path / "conf", rovers=IDS, passwords=PASSWORDS)
    with Mosquitto(tmp_path / "run", conf_path=files.conf) as broker:
        yield broker, files.credentials


@pytest.mark.slow
def test_a_rover_with_a_wrong_password_is_refused_in_one_line(
    acl_broker: tuple[Mosquitto, Path], tmp_path: Path
) -> None:
    broker, _ = acl_broker
    _bundle(tmp_path / "bundles", "red", password="not-red-pw")
    network = broker.ports[1883]  # where rovers log in
    result = sim_rovers("--broker", f"mqtt://127.0.0.1:{network}", "--config-dir", str(tmp_path / "bundles"))
    assert result.exit_code == 2
    assert result.output.strip() == (
        f"Error: broker mqtt://127.0.0.1:{network} refused rover 'red' (user 'red'): not authorised "
        "(check the rover's user and password)"
    )


@pytest.mark.slow
def test_rovers_without_logins_are_told_where_the_logins_are(acl_broker: tuple[Mosquitto, Path]) -> None:
    broker, _ = acl_broker
    network = broker.ports[1883]
    result = sim_rovers("--broker", f"mqtt://127.0.0.1:{network}", "--ids", "red")
    assert result.exit_code == 2
    line = result.output.strip()
    assert len(line.splitlines()) == 1 and line.startswith(f"Error: broker mqtt://127.0.0.1:{network} refused rover")
    assert "--credentials <state dir>/broker-credentials.toml" in line and "broker-config" in line


@pytest.mark.slow
def test_each_rover_connects_with_its_own_credentials_behind_the_acl(acl_broker: tuple[Mosquitto, Path]) -> None:
    broker, credentials = acl_broker
    events: list[FleetEvent] = []
    seen = threading.Condition()

    def on_event(event: FleetEvent) -> None:
        with seen:
            events.append(event)
            seen.notify_all()

    with MqttRecorder(broker.host, broker.port, (ROVER_STATUS_WILDCARD,), "edge", PASSWORDS["edge"]) as rec:
        fleet = start_fleet(f"mqtt://127.0.0.1:{broker.ports[1883]}", credentials=credentials, on_event=on_event)
        try:
            assert rec.wait_for(lambda m: {json.loads(x.payload)["id"] for x in m} == set(IDS), 60)
            with seen:
                assert seen.wait_for(lambda: {e.rover_id for e in events if e.status} == set(IDS), 60)
        finally:
            fleet.close()
        assert rec.wait_for(lambda m: sum(b'"offline"' in x.payload for x in m) == 3, 60)  # each said goodbye
    statuses = [e.status for e in events if e.status is not None]
    assert {(s.id, s.halt, s.formation) for s in statuses} >= {(r, "idle", None) for r in IDS}
    assert {e.text for e in events if e.status is None} >= {"broker connected 1"}


@pytest.mark.slow
@pytest.mark.parametrize("which", ["mosquitto", "embedded"])
def test_two_writers_with_the_same_seq_leave_every_rover_on_the_retained_command(tmp_path: Path, which: str) -> None:
    """Both writers read the retained formation before either publishes (forced), so both publish the same seq;
    each rover (the firmware `sim rovers` runs) applies both, in the broker's order, and ends on the retained one."""
    broker: Any = Mosquitto(tmp_path / "mq") if which == "mosquitto" else EmbeddedBroker("127.0.0.1", 0)
    with broker:
        target = BrokerTarget(embedded=False, host="127.0.0.1", port=broker.port)
        send_formation(target, lambda seq: build_formation("line", IDS, seq=seq, spacing_cm=60.0))
        configs = fleet_configs(IDS, rover_broker(f"mqtt://127.0.0.1:{broker.port}"))
        with MqttRecorder("127.0.0.1", broker.port, (FORMATION_TOPIC, ROVER_STATUS_WILDCARD)) as rec:
            fleet = SimFleet(configs, rover_broker(f"mqtt://127.0.0.1:{broker.port}")).start()
            try:
                assert rec.wait_for(lambda m: len(_latest(m, "line", 1)) == 3, 60)
                both_read = threading.Barrier(2)

                def writer(kind: Any, out: list[Any]) -> None:
                    def make(seq: int) -> Any:
                        both_read.wait(30)  # the other writer has read the retained formation too
                        return build_formation(kind, IDS if kind != "stop" else [], seq=seq)

                    out.append(send_formation(target, make, client_id=f"writer-{kind}"))

                sent: list[Any] = []
                threads = [threading.Thread(target=writer, args=(k, sent)) for k in ("stop", "triangle")]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(60)
                assert [m.seq for m in sent] == [2, 2]  # the same seq: identity cannot be the seq
                retained = retained_now("127.0.0.1", broker.port)
                assert (retained["kind"], retained["seq"]) in {("stop", 2), ("triangle", 2)}
                assert rec.wait_for(lambda m: len(_latest(m, retained["kind"], 2)) == 3, 60), rec.json_on("status")
                barrier = send_formation(target, lambda seq: build_formation("rendezvous", IDS, seq=seq))
                assert rec.wait_for(lambda m: len(_latest(m, "rendezvous", barrier.seq)) == 3, 60)
                for rover in IDS:  # with the barrier arrived, nothing came after the retained command
                    said = [(s["formation"], s["seq"]) for s in rec.json_on(f"/{rover}/status")]
                    before = [x for x in said if x != ("rendezvous", barrier.seq)]
                    assert before[-1] == (retained["kind"], 2), (rover, said)
            finally:
                fleet.close()


def _latest(messages: list[Any], kind: str, seq: int) -> set[str]:
    """Rovers whose newest status says they apply (kind, seq)."""
    latest: dict[str, dict[str, Any]] = {}
    for m in messages:
        if m.topic.startswith("ips/v2/rovers/") and m.payload:
            doc = json.loads(m.payload)
            latest[doc["id"]] = doc
    return {
        r for r, doc in latest.items() if (doc["formation"], doc["seq"]) == (kind, seq) and doc["state"] == "online"
    }


class SimClock:
    """A simulation's clock: time moves only when the simulation says so (what a live twin would hand in)."""

    def __init__(self) -> None:
        self.t_ms = 0

    def now_ms(self) -> int:
        return self.t_ms

    def wait(self, seconds: float, stop: threading.Event) -> bool:
        self.t_ms += round(seconds * 1000)
        return stop.is_set()


def test_the_runner_steps_on_the_clock_it_is_given_and_exposes_the_motor_commands() -> None:
    clock = SimClock()
    rover = HostRover(check_rover_config({"id": "red", "broker": {"host": "none"}}), broker_host=None)
    runner = RoverRunner(rover, clock)
    rover.deliver(FORMATION_TOPIC, dumps(build_formation("rendezvous", ["red", "green"], seq=1)), 0)
    for k in range(25):  # 0.5 s of the simulation's time, at the firmware's 20 ms period
        clock.t_ms = 20 * k
        for rid, (x, y) in {"red": (100.0, 100.0), "green": (300.0, 100.0)}.items():
            pose = encode_pose(rid, k, k, 1.7e9 + clock.t_ms / 1000, x, y, 0.0, None, None, 1.0)  # t: capture time
            rover.deliver(pose_topic(rid), pose, clock.t_ms)
        runner.step()
    assert rover.rover._last_step == 480  # the firmware ran on the simulation's clock, not the host's
    assert runner.halt == "none"
    left, right = runner.wheel_speeds_cm_s
    assert left > 0 and right > 0  # red drives towards green (heading 0, green ahead)
    assert runner.motor_state.left_duty > 0 and runner.motor_state.right_duty > 0
