"""`broker-config`'s files enforced by a real Mosquitto: client ids tied to logins, TLS, sizes, last wills."""

from __future__ import annotations

import resource
import selectors
import socket
import ssl
import time
from collections.abc import Iterator
from pathlib import Path
from typing import cast

import pytest

from edge.broker import BrokerFiles, read_credentials, write_mosquitto_config, write_password_file
from edge.broker.access import MAX_PACKET_BYTES, MAX_PAYLOAD_BYTES
from edge.broker.mosquitto import LOCAL_PORT, NETWORK_MAX_CONNECTIONS, TLS_PORT
from edge.config import BrokerTarget
from edge.messages import FORMATION_TOPIC, edge_status_topic, rover_status_topic
from edge.mqttclient import TlsFiles
from edge.publisher import MqttPublisher
from tests.support.mosquitto import Mosquitto
from tests.support.probe import Probe, edge_states_until_marker

ROVERS = ["red", "green", "blue"]
EDGE_ID = "edge-1"


@pytest.fixture
def deployed(tmp_path: Path) -> Iterator[tuple[Mosquitto, BrokerFiles]]:
    files = write_mosquitto_config(
        tmp_path / "conf", rovers=ROVERS, edge_id=EDGE_ID, tls_port=TLS_PORT, tls_names=["localhost", "127.0.0.1"]
    )
    with Mosquitto(tmp_path / "run", conf_path=files.conf) as broker:
        yield broker, files


def logins(files: BrokerFiles) -> dict[str, dict[str, str]]:
    creds = read_credentials(files.credentials)
    found = {"edge": creds.edge, **creds.rovers}
    return {user: {"user": login.username, "password": login.password} for user, login in found.items()}


@pytest.mark.slow
def test_a_rover_login_with_the_edges_client_id_does_not_disconnect_the_edge(
    deployed: tuple[Mosquitto, BrokerFiles],
) -> None:
    broker, files = deployed
    users = logins(files)
    local, network = broker.ports[LOCAL_PORT], broker.ports[1883]
    edge_login = users["edge"]
    target = BrokerTarget(False, "127.0.0.1", local, username=edge_login["user"], password=edge_login["password"])
    publisher = MqttPublisher(target, edge_id=EDGE_ID, rovers=ROVERS, reconnect_min_s=0.1, reconnect_max_s=0.2)
    publisher.start()
    try:
        assert publisher.wait_connected(10)
        with Probe("127.0.0.1", local, client_id="watch", **users["edge"]) as watcher:
            watcher.subscribe(edge_status_topic(EDGE_ID))
            watcher.subscribe(rover_status_topic("red"))
            # On the network listener the client id becomes the user name: "red" takes over nobody but itself.
            with Probe("127.0.0.1", network, client_id=f"edge-ips-{EDGE_ID}", **users["red"]) as red:
                assert red.accepted
                red.publish(rover_status_topic("red"), b'{"marker":1}')
                assert watcher.wait_payload(rover_status_topic("red"), b'{"marker":1}')
            states = edge_states_until_marker(publisher, watcher, EDGE_ID)
        assert "offline" not in states  # no last will: the edge's session was never taken
        assert publisher.connected and publisher.stats.disconnects == 0
    finally:
        publisher.stop()


@pytest.mark.slow
@pytest.mark.parametrize("login", ["red", "viewer"])
def test_no_login_but_the_edges_connects_to_the_local_listener_where_clients_keep_their_ids(
    deployed: tuple[Mosquitto, BrokerFiles], login: str
) -> None:
    broker, files = deployed
    creds = read_credentials(files.credentials)
    assert creds.viewer is not None
    other = {"red": creds.rovers["red"], "viewer": creds.viewer}[login]
    local = broker.ports[LOCAL_PORT]
    edge_login = creds.edge
    target = BrokerTarget(False, "127.0.0.1", local, username=edge_login.username, password=edge_login.password)
    publisher = MqttPublisher(target, edge_id=EDGE_ID, rovers=ROVERS, reconnect_min_s=0.1, reconnect_max_s=0.2)
    publisher.start()
    try:
        assert publisher.wait_connected(10)
        with Probe("127.0.0.1", local, client_id="edge-ips-watch", user="edge", password=edge_login.password) as w:
            w.subscribe(edge_status_topic(EDGE_ID))
            # Here a client keeps the id it asks for: a rover's login (read out of its flash) with the edge's id
            # would take the edge's session and make the broker publish its last will.
            intruder = Probe(
                "127.0.0.1", local, client_id=f"edge-ips-{EDGE_ID}", user=other.username, password=other.password
            )
            with intruder:
                assert not intruder.accepted
            states = edge_states_until_marker(publisher, w, EDGE_ID)
        assert "offline" not in states
        assert publisher.connected and publisher.stats.disconnects == 0
    finally:
        publisher.stop()


@pytest.mark.slow
def test_the_tls_listener_takes_the_edge_with_the_client_certificate_and_nobody_without(
    deployed: tuple[Mosquitto, BrokerFiles],
) -> None:
    broker, files = deployed
    assert files.tls is not None
    users = logins(files)
    for key in (files.tls.server_key, files.tls.client_key, files.passwd, files.credentials):
        assert key.stat().st_mode & 0o777 == 0o600
    port = broker.ports[TLS_PORT]
    tls = TlsFiles(files.tls.ca_cert, files.tls.client_cert, files.tls.client_key)
    target = BrokerTarget(False, "localhost", port, tls=True, username="edge", password=users["edge"]["password"])
    publisher = MqttPublisher(target, edge_id=EDGE_ID, rovers=ROVERS, tls=tls)
    publisher.start()
    try:
        assert publisher.wait_connected(10)
    finally:
        publisher.stop()
    no_certificate = {"ca_certs": str(files.tls.ca_cert), "cert_reqs": ssl.CERT_REQUIRED}
    with Probe("localhost", port, client_id="rover-red", tls=no_certificate, **users["red"]) as red:
        assert not red.accepted  # the handshake fails before any login is read
    certificate = {**no_certificate, "certfile": str(files.tls.client_cert), "keyfile": str(files.tls.client_key)}
    with Probe("localhost", port, client_id=f"edge-ips-{EDGE_ID}", tls=certificate, **users["red"]) as red:
        assert not red.accepted  # with the certificate, still no rover login (clients keep their ids here)
    with Probe("localhost", broker.ports[1883], client_id="x", tls=no_certificate, **users["red"]) as plain:
        assert not plain.accepted  # the plain listener speaks no TLS


@pytest.mark.slow
def test_the_viewer_reads_over_tls_on_its_own_listener_and_cannot_take_the_edges_session(
    deployed: tuple[Mosquitto, BrokerFiles],
) -> None:
    """On 8883 clients keep their ids (the edge's share one login), so it takes the edge's login only; the viewer
    has 8884, where a client's id is its user name: its password and the certificate read, and take nothing."""
    broker, files = deployed
    assert files.tls is not None and files.tls_viewer_passwd is not None
    assert files.tls_viewer_passwd.stat().st_mode & 0o777 == 0o600
    creds = read_credentials(files.credentials)
    assert creds.viewer is not None
    viewer = {"user": creds.viewer.username, "password": creds.viewer.password}
    certificate = {
        "ca_certs": str(files.tls.ca_cert),
        "cert_reqs": ssl.CERT_REQUIRED,
        "certfile": str(files.tls.client_cert),
        "keyfile": str(files.tls.client_key),
    }
    tls = TlsFiles(files.tls.ca_cert, files.tls.client_cert, files.tls.client_key)
    target = BrokerTarget(
        False, "localhost", broker.ports[TLS_PORT], tls=True, username="edge", password=creds.edge.password
    )
    publisher = MqttPublisher(target, edge_id=EDGE_ID, rovers=ROVERS, tls=tls, reconnect_min_s=0.1, reconnect_max_s=0.2)
    publisher.start()
    try:
        assert publisher.wait_connected(10)
        edge_login = {"user": "edge", "password": creds.edge.password}
        with Probe("127.0.0.1", broker.ports[LOCAL_PORT], client_id="edge-ips-watch", **edge_login) as watcher:
            watcher.subscribe(edge_status_topic(EDGE_ID))
            edges = broker.ports[TLS_PORT]
            with Probe("localhost", edges, client_id=f"edge-ips-{EDGE_ID}", tls=certificate, **viewer) as on_edges:
                assert not on_edges.accepted  # the edge's TLS listener: the edge's login only
            viewers = broker.ports[TLS_PORT + 1]
            with Probe("localhost", viewers, client_id=f"edge-ips-{EDGE_ID}", tls=certificate, **viewer) as taker:
                assert taker.accepted  # as "viewer": the id it asked for is not the one it gets
                taker.subscribe(edge_status_topic(EDGE_ID))
                assert "offline" not in edge_states_until_marker(publisher, taker, EDGE_ID)  # it reads over TLS
            states = edge_states_until_marker(publisher, watcher, EDGE_ID)
        assert "offline" not in states  # no last will: the edge's session was never taken
        assert publisher.connected and publisher.stats.disconnects == 0
    finally:
        publisher.stop()


@pytest.mark.slow
def test_oversized_messages_are_refused_by_mosquitto(deployed: tuple[Mosquitto, BrokerFiles]) -> None:
    broker, files = deployed
    users = logins(files)
    with Probe("127.0.0.1", broker.port, client_id="edge-ips-x", **users["edge"]) as edge:
        edge.publish(FORMATION_TOPIC, b'{"fits":1}', retain=True)
        edge.publish(FORMATION_TOPIC, b" " * (MAX_PAYLOAD_BYTES + 1), retain=True)  # dropped
        edge.client.publish(FORMATION_TOPIC, b"x" * (2 << 20), qos=1, retain=True)
        assert edge.wait(lambda: edge.disconnects > 0)
    with Probe("127.0.0.1", broker.port, client_id="late", **users["edge"]) as late:
        late.subscribe(FORMATION_TOPIC)
        assert late.wait(lambda: len(late.received) == 1)
        assert late.payloads(FORMATION_TOPIC) == [b'{"fits":1}']
    assert MAX_PACKET_BYTES > MAX_PAYLOAD_BYTES + 64


@pytest.mark.slow
def test_a_rovers_last_will_cannot_set_the_formation(deployed: tuple[Mosquitto, BrokerFiles]) -> None:
    broker, files = deployed
    users = logins(files)
    network = broker.ports[1883]
    with Probe("127.0.0.1", broker.port, client_id="edge-ips-watch", **users["edge"]) as watcher:
        watcher.subscribe(FORMATION_TOPIC)
        watcher.subscribe(rover_status_topic("red"))
        will = (FORMATION_TOPIC, b'{"v":1,"seq":7,"kind":"line"}')
        red = Probe("127.0.0.1", network, client_id="rover-red", will=will, **users["red"])
        assert red.accepted
        red.client.loop_stop()
        red.client.socket().close()  # vanish: Mosquitto checks the will against the ACL before it publishes it
        with Probe("127.0.0.1", network, client_id="rover-red", **users["red"]) as again:  # the old session is gone
            again.publish(rover_status_topic("red"), b'{"marker":1}')
        assert watcher.wait_payload(rover_status_topic("red"), b'{"marker":1}')
        assert watcher.payloads(FORMATION_TOPIC) == []


@pytest.mark.slow
def test_mosquitto_accepts_the_python_hash(tmp_path: Path) -> None:
    password = "pä$$word with spaces"
    passwd = write_password_file(tmp_path / "passwd", {"edge": password})
    assert passwd.stat().st_mode & 0o777 == 0o600 and passwd.read_text().startswith("edge:$7$101$")
    with Mosquitto(tmp_path / "run", users={"edge": password}) as broker:  # its passwd: write_password_file's
        with Probe("127.0.0.1", broker.port, user="edge", password=password) as right:
            assert right.accepted
        with Probe("127.0.0.1", broker.port, user="edge", password="pa$$word with spaces") as wrong:
            assert not wrong.accepted


@pytest.mark.slow
def test_silent_sockets_from_the_network_leave_the_edge_room_on_its_own_listener(tmp_path: Path) -> None:
    """Mosquitto never closes a socket that sends no CONNECT, and under systemd it has 1024 file descriptors: a
    host opening more silent sockets than that on 1883 took them all, and the edge (its reconnection, the
    dashboard's STOP, `edge-ips formation`: new connections to the loopback listener) was refused."""
    files = write_mosquitto_config(tmp_path / "conf", rovers=ROVERS, edge_id=EDGE_ID)
    creds = read_credentials(files.credentials)
    flood = 1100  # more than the 1024 descriptors systemd gives the service
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < flood + 200:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, flood + 200), hard))  # this process holds the flood
    silent: list[socket.socket] = []
    try:
        with Mosquitto(tmp_path / "run", conf_path=files.conf, open_files=1024) as broker:
            for _ in range(flood):
                try:
                    silent.append(socket.create_connection(("127.0.0.1", broker.ports[1883]), timeout=2))
                except OSError:
                    break  # the broker's queue of sockets to accept is full: it accepts no more
            beyond = len(silent) - NETWORK_MAX_CONNECTIONS
            closed = _closed_by_peer(silent, beyond)
            assert beyond > 0 and len(closed) >= beyond  # beyond the cap: closed as they arrive
            for sock in closed:  # (this process's own descriptors: paho's select() takes none above 1023)
                sock.close()
            target = BrokerTarget(
                False, "127.0.0.1", broker.ports[LOCAL_PORT], username="edge", password=creds.edge.password
            )
            publisher = MqttPublisher(target, edge_id=EDGE_ID, rovers=ROVERS)
            publisher.start()
            try:
                assert publisher.wait_connected(30)  # the edge's listener still has room
            finally:
                publisher.stop()
    finally:
        for sock in silent:
            sock.close()
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def _closed_by_peer(socks: list[socket.socket], wanted: int, guard_s: float = 60.0) -> list[socket.socket]:
    """Those of ``socks`` the broker closed, once ``wanted`` of them are (``guard_s``: a failure guard)."""
    selector = selectors.DefaultSelector()  # epoll: more sockets than select() takes
    for sock in socks:
        sock.setblocking(False)
        selector.register(sock, selectors.EVENT_READ)
    closed: list[socket.socket] = []
    deadline = time.monotonic() + guard_s
    while len(closed) < wanted and time.monotonic() < deadline:
        for key, _ in selector.select(timeout=deadline - time.monotonic()):
            try:
                data = cast(socket.socket, key.fileobj).recv(1)
            except BlockingIOError:
                continue
            except OSError:
                data = b""
            if data == b"":
                closed.append(cast(socket.socket, key.fileobj))
                selector.unregister(key.fileobj)
    selector.close()
    return closed
