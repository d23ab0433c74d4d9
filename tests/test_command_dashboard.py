"""The dashboard shows what the rovers report (their retained rover status v2), not what the edge remembers: the pure
event, the watcher against a real Mosquitto (forged statuses refused), and the page in Debian's chromium."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import paho.mqtt.client as mqtt
import pytest

from edge.commands import build_formation
from edge.config import BrokerTarget
from edge.dashboard.events import rovers_event
from edge.dashboard.formation import FormationDesk
from edge.messages import FORMATION_TOPIC, RoverStatusV2, dumps, rover_status_topic
from tests.support.appliance import edge_config, running
from tests.support.dashboard import call, chromium, read_events
from tests.support.mosquitto import Mosquitto

IDS = ["red", "green", "blue"]
WAIT_MS = 60_000


def report(rover_id: str, halt: str = "stop", kind: str | None = "stop", seq: int | None = 7, **kw: Any) -> bytes:
    fields = {"v": 2, "id": rover_id, "state": "online", "halt": halt, "formation": kind, "seq": seq, "fw": "0.2.0"}
    return dumps(RoverStatusV2(**{**fields, **kw}))


def as_report(payload: bytes) -> RoverStatusV2:
    return RoverStatusV2.model_validate_json(payload)


def shown(halt: str, kind: str | None, seq: int | None, on_retained: bool) -> dict[str, Any]:
    return {"id": "red", "reported": True, "state": "online", "halt": halt, "formation": kind, "seq": seq,
            "fw": "0.2.0", "on_retained": on_retained}  # fmt: skip


@pytest.mark.parametrize(
    ("what", "reports", "retained", "want"),
    [
        ("no status yet", {}, None, {"id": "red", "reported": False}),
        ("on the broker's stop", {"red": report("red")}, {"kind": "stop", "seq": 7}, shown("stop", "stop", 7, True)),
        (
            "same seq, another kind (two writers at once)",
            {"red": report("red", "none", "line", 7)},
            {"kind": "stop", "seq": 7},
            shown("none", "line", 7, False),
        ),
        (
            "forgotten after a reconnect",
            {"red": report("red", "idle", None, None)},
            {"kind": "line", "seq": 3},
            shown("idle", None, None, False),
        ),
    ],
)
def test_the_rovers_event_is_what_each_rover_reports(
    what: str, reports: dict[str, bytes], retained: dict[str, Any] | None, want: dict[str, Any]
) -> None:
    event = rovers_event(["red"], {k: as_report(v) for k, v in reports.items()}, retained)
    assert event["rovers"] == [want], what
    assert event["retained"] == retained


class Rovers:
    """Publishes rover statuses as rovers (and forgers) would, retained."""

    def __init__(self, broker: Mosquitto) -> None:
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="rovers")
        self.client.connect(broker.host, broker.port)
        self.client.loop_start()

    def say(self, topic: str, payload: bytes) -> None:
        self.client.publish(topic, payload, qos=1, retain=True).wait_for_publish(10)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


@pytest.fixture
def rovers(mosquitto: Mosquitto) -> Iterator[Rovers]:
    r = Rovers(mosquitto)
    yield r
    r.close()


@pytest.mark.slow
def test_the_watcher_keeps_each_rovers_own_status_and_refuses_forgeries(mosquitto: Mosquitto, rovers: Rovers) -> None:
    seen: list[tuple[str, str | None]] = []
    changed = threading.Condition()

    def on_report(rover_id: str, r: RoverStatusV2 | None) -> None:
        with changed:
            seen.append((rover_id, None if r is None else r.halt))
            changed.notify_all()

    def wait_for(n: int) -> None:
        with changed:
            assert changed.wait_for(lambda: len(seen) >= n, timeout=30), seen

    target = BrokerTarget(embedded=False, host=mosquitto.host, port=mosquitto.port)
    desk = FormationDesk(target, edge_id="edge-t", rover_ids=IDS, token=None, on_report=on_report)
    rovers.say(rover_status_topic("red"), report("red", "none", "line", 3))  # retained before the watcher starts
    desk.start()
    try:
        wait_for(1)  # red's retained status arrived: the watcher is subscribed, so what follows reaches it live
        forged = [
            (rover_status_topic("green"), report("red")),  # red's status on green's topic
            (rover_status_topic("mallory"), report("mallory")),  # not a configured rover
            (rover_status_topic("blue"), b'{"v":1,"id":"blue","state":"online","halt":"none","formation":3,"fw":"x"}'),
            (rover_status_topic("blue"), b"not json"),
            # blue's own status, padded past the contract's 160 bytes (a broker's 512-byte limit lets it through)
            (rover_status_topic("blue"), report("blue", "none", "line", 3)[:-1] + b" " * 200 + b"}"),
        ]
        for topic, payload in forged:
            rovers.say(topic, payload)
        rovers.say(rover_status_topic("blue"), report("blue", "stop", "stop", 4))  # after the forgeries, in order
        wait_for(2)
        assert seen == [("red", "none"), ("blue", "stop")]
        assert set(desk.reports) == {"red", "blue"}
        assert (desk.reports["red"].halt, desk.reports["red"].formation) == ("none", "line")
        assert desk.refused_reports == len(forged)
        rovers.say(rover_status_topic("red"), b"")  # a cleared retained status forgets the rover
        wait_for(3)
        assert seen[2] == ("red", None) and set(desk.reports) == {"blue"}
    finally:
        desk.close()


@pytest.mark.slow
def test_the_page_and_the_api_show_what_the_rovers_report(mosquitto: Mosquitto, rovers: Rovers) -> None:
    rovers.say(FORMATION_TOPIC, dumps(build_formation("line", IDS, seq=8, spacing_cm=60.0)))
    config = edge_config(**{"http.enabled": True, "http.port": 0, "broker.url": mosquitto.url})
    with running(config) as app, chromium() as browser:
        port = app.http.port
        rovers.say(rover_status_topic("red"), report("red", "none", "line", 8))
        rovers.say(rover_status_topic("green"), report("green", "stale", "line", 8))
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(f"http://127.0.0.1:{port}/")
        cell = "id => document.querySelector(`tr[data-rover='${id}'] td.halt`)?.dataset.halt"
        page.wait_for_function(f"() => ({cell})('green') === 'stale'", timeout=WAIT_MS)
        # The appliance's stop at start (seq 9) is what the broker holds; the rovers still say line 8: flagged.
        applies = page.locator("tr[data-rover='red'] td.applies")
        assert applies.text_content() == "line (seq 8)" and "off-retained" in (applies.get_attribute("class") or "")
        assert page.locator("tr[data-rover='blue'] td.halt").text_content() == "no status"
        rovers.say(rover_status_topic("red"), report("red", "stop", "stop", 9))  # red obeys the stop
        page.wait_for_function(f"() => ({cell})('red') === 'stop'", timeout=WAIT_MS)
        assert applies.text_content() == "stop (seq 9)" and "off-retained" not in (applies.get_attribute("class") or "")
        api = call(port, "GET", "/api/rovers").json()
        assert api["retained"] == {"kind": "stop", "seq": 9}
        assert [(r["id"], r.get("halt"), r.get("on_retained")) for r in api["rovers"]] == [
            ("red", "stop", True),
            ("green", "stale", False),
            ("blue", None, None),
        ]
        first = read_events(port, {"rovers": 1})["rovers"][0]  # a new page learns them at once
        assert first == api
        page.close()
