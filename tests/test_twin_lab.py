"""The twin's lab behind its socket, as the appliance and an operator reach it: the camera stream read by
:class:`TwinSource`, the controls (scatter, faults) through :class:`LabClient`, and the rovers' firmware on a real
(embedded) broker. One lab serves the module's tests."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
import pytest

from edge.broker import EmbeddedBroker
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.errors import ConfigError, SimulationError, SourceError
from edge.messages import encode_pose, pose_topic
from edge.sim.fleet import FleetBroker, fleet_configs
from edge.sim.link import LinkSettings
from edge.sim.twin.lab import LabEvents, LabSettings, TwinLab
from edge.sim.twin.server import LabServer
from edge.sim.twin.source import LabClient, TwinSource
from edge.sim.twin.wire import ControlRequest, read_line, send_line, socket_path

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # a lab with three rovers on a broker: seconds

IDS = ["red", "green", "blue"]
WAIT_S = 60.0  # a failure guard: how long something may take before the test fails


class Watched(LabEvents):
    """The lab's events, with a wait for one that matches."""

    def __init__(self) -> None:
        super().__init__()
        self.changed = threading.Condition()

    def add(self, who: str, text: str, **data: Any) -> None:
        super().add(who, text, **data)
        with self.changed:
            self.changed.notify_all()

    def wait_for(self, who: str, fragment: str, after: int = 0) -> dict[str, Any]:
        def found() -> dict[str, Any] | None:
            return next((e for e in self.recent(after) if e["who"] == who and fragment in e["text"]), None)

        with self.changed:
            assert self.changed.wait_for(found, WAIT_S), f"{who}: no {fragment!r} in {self.recent()}"
        hit = found()
        assert hit is not None
        return hit


class Publisher:
    """Poses published straight to the broker (what the edge would send), for the link tests."""

    def __init__(self, port: int) -> None:
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-poses")
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def __enter__(self) -> Callable[[str, int], None]:
        def publish(rover_id: str, seq: int) -> None:
            payload = encode_pose(rover_id, seq, seq, time.time(), 100.0, 100.0, 0.0, 0.0, 0.0, 1.0)
            self.client.publish(pose_topic(rover_id), payload, qos=0).wait_for_publish(WAIT_S)

        return publish

    def __exit__(self, *exc: object) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@pytest.fixture(scope="module")
def broker_port() -> Iterator[int]:
    broker = EmbeddedBroker("127.0.0.1", 0).start()
    try:
        yield broker.port
    finally:
        broker.stop()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory, broker_port: int) -> Iterator[tuple[TwinLab, Path, Watched]]:
    events = Watched()
    configs = fleet_configs(IDS, FleetBroker("127.0.0.1", broker_port))
    # A link that loses the association after half a second without the access point (the ESP8266's takes 8.5 s):
    # so a fault of a second shows the firmware dropping its connection and making a new one.
    link = LinkSettings(drop_s=0.5, rejoin_s=0.3)
    twin = TwinLab(LabSettings(rovers=3, seed=4, link=link), configs, events=events).start()
    path = socket_path(tmp_path_factory.mktemp("lab"))
    server = LabServer(path, twin).start()
    twin.start_rovers()
    for rover_id in IDS:
        events.wait_for(rover_id, "broker connected")
    try:
        yield twin, path, events
    finally:
        server.close()
        twin.close()


def test_the_source_opens_on_the_lab_camera_and_names_its_model_and_rovers(lab: tuple[TwinLab, Path, Watched]) -> None:
    twin, path, _ = lab
    source = TwinSource(path)
    info = source.open()
    try:
        assert (info.width_px, info.height_px, info.fps) == (1280, 720, 30.0)
        assert "twin lab: 3 rovers (red, green, blue)" in info.description
        assert np.allclose(source.camera.camera_matrix, twin.camera_model.camera_matrix)
        assert np.allclose(source.camera.tvec, twin.camera_model.tvec)
        assert [r.id for r in source.rover_configs()] == IDS
        calibration = source.exact_calibration()
        assert (calibration.width_px, calibration.height_px) == (1280, 720)
        assert all(r.front_color_bgr is not None for r in source.rover_configs())  # two-tone markers
        frames = [source.read() for _ in range(4)]
    finally:
        source.close()
    numbers = [f.index for f in frames if f is not None]
    assert len(numbers) == 4 and numbers == sorted(set(numbers))
    image = frames[-1].image if frames[-1] is not None else None
    assert image is not None and image.shape == (720, 1280, 3) and image.std() > 5.0  # a picture, not a blank


def test_a_hung_camera_makes_a_read_fail_and_a_reopened_source_reads_again(lab: tuple[TwinLab, Path, Watched]) -> None:
    _, path, events = lab
    source = TwinSource(path, read_timeout_s=0.5)
    source.open()
    try:
        assert source.read() is not None
        mark = events.count
        LabClient(path).fault("camera", 2.0)
        with pytest.raises(SourceError, match=r"no frame for 0\.5 s"):
            for _ in range(30):  # frames already on their way may still come
                source.read()
        source.close()
        events.wait_for("lab", "fault over: camera hung for 2 s", after=mark)
        source.open()
        assert source.read() is not None
    finally:
        source.close()


def test_scatter_puts_every_rover_on_a_free_spot_well_inside_the_area(lab: tuple[TwinLab, Path, Watched]) -> None:
    twin, path, _ = lab
    placed = LabClient(path).scatter()
    xy = np.array([placed[r] for r in IDS])
    assert np.all(xy[:, 0] >= 40.0) and np.all(xy[:, 0] <= AREA_WIDTH_CM - 40.0)
    assert np.all(xy[:, 1] >= 40.0) and np.all(xy[:, 1] <= AREA_LENGTH_CM - 40.0)
    gaps = [np.hypot(*(xy[i] - xy[j])) for i in range(3) for j in range(i + 1, 3)]
    assert min(gaps) >= 150.0 - 0.1
    truth = twin.state().by_id()
    for rover_id in IDS:
        assert (truth[rover_id].x_cm, truth[rover_id].y_cm) == pytest.approx(placed[rover_id], abs=0.1)


def test_a_short_wifi_fault_holds_the_poses_back_and_the_connection_survives(
    lab: tuple[TwinLab, Path, Watched], broker_port: int
) -> None:
    twin, path, events = lab
    green = next(r for r in twin.rovers if r.id == "green")
    mark = events.count
    sent: list[int] = []
    with Publisher(broker_port) as publish:
        # A pose is QoS 0: one sent while green is still (re)connecting after the test before is lost, so send it
        # again until green has it (each wait is for the firmware's own thread to take it; the count bounds the
        # whole at about WAIT_S).
        assert any(publish("green", 0) or green.wait_own_pose(0, 0.5) for _ in range(int(WAIT_S / 0.5)))
        assert LabClient(path).fault("wifi", 0.4, "green") == "green's Wi-Fi gone for 0.4 s"
        for seq in range(1, 5):  # into the outage: TCP keeps them, they arrive when it is over
            publish("green", seq)
            sent.append(seq)
        events.wait_for("green", "fault over: green's Wi-Fi gone for 0.4 s", after=mark)
        assert green.wait_own_pose(sent[-1], WAIT_S)
    assert max(green.pose_delays_s()) > 0.1  # held back by the outage, not lost
    assert not [e for e in events.recent(mark) if "link down" in e["text"]]  # the association held


def test_a_control_client_waits_on_the_lab_for_its_next_event_and_for_a_rover_driving(
    lab: tuple[TwinLab, Path, Watched],
) -> None:
    """``wait`` answers when it is met (no client polls the lab): an event after the one named, a rover at a speed."""
    _, path, events = lab
    client = LabClient(path)
    mark = events.count
    waited: list[dict[str, Any]] = []
    waiter = threading.Thread(target=lambda: waited.append(client.wait_event(mark, WAIT_S)))
    waiter.start()
    client.note("a marker for the waiting client")
    waiter.join(WAIT_S)
    (status,) = waited
    assert status["met"] and any(e["text"] == "fault: a marker for the waiting client" for e in status["events"])
    assert all(e["n"] > mark for e in status["events"])
    assert client.wait_event(mark - 1, WAIT_S)["met"]  # one came already: answered at once
    assert client.wait_driving(0.0, WAIT_S)["met"]  # every rover drives at 0 cm/s or faster
    with pytest.raises(SimulationError, match="a wait is for an event or for driving, not 'rest'"):
        client.request(ControlRequest("wait", kind="rest", seconds=1.0))


def test_a_long_wifi_fault_loses_the_association_and_the_rover_reconnects_after(
    lab: tuple[TwinLab, Path, Watched],
) -> None:
    _, path, events = lab
    mark = events.count
    done = LabClient(path).fault("wifi", 1.5, "blue")
    assert done == "blue's Wi-Fi gone for 1.5 s, the association with it"
    start = events.wait_for("blue", "fault: blue's Wi-Fi", after=mark)
    down = events.wait_for("blue", "broker link down: wifi lost", after=mark)
    back = events.wait_for("blue", "broker connected", after=down["n"])
    assert down["t"] - start["t"] >= 0.5 - 0.05  # the station noticed at drop_s, not at once
    assert back["t"] - start["t"] >= 1.5 + 0.3 - 0.05  # associated again rejoin_s after the access point is back
    assert not [e for e in events.recent(mark) if e["who"] in ("red", "green") and "link down" in e["text"]]
    status = LabClient(path).status(after=mark)
    assert any("fault: blue's Wi-Fi gone" in e["text"] for e in status["events"])


@pytest.mark.parametrize(
    ("kind", "seconds", "rover", "why"),
    [
        ("wifi", 1.0, "purple", "no rover 'purple' in the lab"),
        ("wifi", 1.0, None, "which rover?"),
        ("camera", 0.0, None, "a fault lasts more than 0"),
        ("camera", 301.0, None, "at most 300 s"),
        ("broker", 1.0, None, "the lab causes wifi and camera faults"),
    ],
)
def test_the_lab_refuses_a_fault_it_cannot_cause_with_the_reason(
    lab: tuple[TwinLab, Path, Watched], kind: str, seconds: float, rover: str | None, why: str
) -> None:
    with pytest.raises(SimulationError, match=why):
        LabClient(lab[1]).fault(kind, seconds, rover)


@pytest.mark.parametrize(
    ("request_line", "error"),
    [
        ({"v": 2, "want": "camera"}, "protocol version 2"),
        ({"v": 1, "want": "control", "do": "dance"}, "unknown request 'dance'"),
        ({"v": 1, "want": "control", "do": "fault", "kind": "camera", "seconds": "soon"}, "could not convert"),
    ],
)
def test_a_request_the_lab_does_not_understand_gets_a_one_line_error(
    lab: tuple[TwinLab, Path, Watched], request_line: dict[str, Any], error: str
) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(WAIT_S)
        sock.connect(str(lab[1]))
        send_line(sock, request_line)
        reply = read_line(sock)
    assert reply["ok"] is False and error in reply["error"]


def test_a_second_lab_on_the_same_socket_is_refused_and_a_dead_labs_socket_is_replaced(
    lab: tuple[TwinLab, Path, Watched], tmp_path: Path
) -> None:
    twin, path, _ = lab
    with pytest.raises(SimulationError, match="a twin lab already runs there"):
        LabServer(path, twin).start()
    stale = tmp_path / "twin.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as dead:
        dead.bind(str(stale))  # a socket file nobody listens on: a lab that was killed
    server = LabServer(stale, twin).start()
    try:
        assert LabClient(stale).status()["ok"]
    finally:
        server.close()
    assert not stale.exists()


def test_without_a_lab_the_source_and_the_controls_say_how_to_start_one(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r"no twin lab answers at .*start one with `edge-ips sim twin`"):
        TwinSource(tmp_path / "twin.sock").open()
    with pytest.raises(SimulationError, match=r"twin lab at .*twin\.sock"):
        LabClient(tmp_path / "twin.sock").scatter()


def test_a_state_directory_too_deep_for_a_unix_socket_is_a_configuration_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="too long for a Unix socket"):
        socket_path(tmp_path / ("d" * 120))
