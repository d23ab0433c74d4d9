"""The embedded broker with logins, as an attacker on the lab's network would try it (paho clients over TCP)."""

from __future__ import annotations

import ipaddress
import logging
import socket
import struct
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.broker import BrokerAccess, Credentials, EmbeddedBroker, ensure_credentials
from edge.broker.access import MAX_PACKET_BYTES, Policy, payload_limit
from edge.broker.embedded import AMQTT_LINES_PER_MINUTE, MAX_PENDING_CONNECTS, MAX_PENDING_PER_ADDRESS, PendingConnects
from edge.broker.gate import IDENTIFIER_REJECTED, NOT_AUTHORIZED, PacketLimit, PacketTooLarge
from edge.config import BrokerTarget
from edge.messages import FORMATION_TOPIC, ROVER_STATUS_WILDCARD, edge_status_topic, pose_topic, rover_status_topic
from edge.publisher import MqttPublisher
from tests.support.probe import OtherHost, Probe, _free_subnet, edge_states_until_marker, other_host

ROVERS = ["red", "green", "blue"]
EDGE_ID = "edge-t"


class Refusals(logging.Handler):
    """The broker's refusal lines, waited on: a refused publish is logged before anything could deliver it."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []
        self._cond = threading.Condition()

    def emit(self, record: logging.LogRecord) -> None:
        with self._cond:
            self.lines.append(record.getMessage())
            self._cond.notify_all()

    def wait_for(self, text: str, timeout_s: float = 10.0) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: any(text in line for line in self.lines), timeout=timeout_s)


@pytest.fixture
def refusals() -> Iterator[Refusals]:
    handler = Refusals()
    logger = logging.getLogger("edge.broker")
    logger.addHandler(handler)
    old = logger.level
    logger.setLevel(logging.INFO)
    yield handler
    logger.removeHandler(handler)
    logger.setLevel(old)


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[tuple[EmbeddedBroker, Credentials]]:
    credentials = ensure_credentials(tmp_path / "state", ROVERS)
    access = BrokerAccess.of(credentials, EDGE_ID, tmp_path / "state" / "broker-credentials.toml")
    with EmbeddedBroker("0.0.0.0", 0, access) as broker:
        yield broker, credentials


def login(credentials: Credentials, user: str) -> dict[str, str]:
    found = credentials.edge if user == "edge" else credentials.rovers[user]
    return {"user": found.username, "password": found.password}


def test_a_rover_login_publishes_its_own_status_and_nothing_else(
    secured: tuple[EmbeddedBroker, Credentials], refusals: Refusals
) -> None:
    broker, creds = secured
    with (
        Probe("127.0.0.1", broker.port, client_id="watcher") as watcher,
        Probe("127.0.0.1", broker.port, client_id="rover-red", **login(creds, "red")) as red,
        Probe("127.0.0.1", broker.port, client_id=f"edge-ips-{EDGE_ID}", **login(creds, "edge")) as edge,
    ):
        assert watcher.accepted and red.accepted and edge.accepted
        watcher.subscribe("ips/v1/#")
        watcher.subscribe(ROVER_STATUS_WILDCARD)
        red.publish(FORMATION_TOPIC, b'{"forged":"formation"}', retain=True)
        red.publish(pose_topic("blue"), b'{"forged":"pose"}')
        red.publish(rover_status_topic("green"), b'{"forged":"status"}', retain=True)
        red.publish(rover_status_topic("red"), b'{"marker":1}', retain=True)  # same connection: after the others
        assert watcher.wait_payload(rover_status_topic("red"), b'{"marker":1}')
        edge.publish(FORMATION_TOPIC, b'{"edge":"formation"}', retain=True)
        assert watcher.wait_payload(FORMATION_TOPIC, b'{"edge":"formation"}')
        forged = [m.payload for m in watcher.received if b"forged" in m.payload]
    assert forged == []
    assert refusals.wait_for(f"a publish on {FORMATION_TOPIC} from 'red': not in its rights")


def test_anonymous_clients_on_this_machine_only_read(
    secured: tuple[EmbeddedBroker, Credentials], refusals: Refusals
) -> None:
    broker, _ = secured
    with Probe("127.0.0.1", broker.port, client_id="viewer-1") as anonymous:
        assert anonymous.accepted
        assert anonymous.subscribe("ips/v1/#") == 1
        assert anonymous.subscribe("#") == 0x80  # beyond the viewer's rights
        anonymous.publish(FORMATION_TOPIC, b'{"anonymous":1}', retain=True)
        assert refusals.wait_for(f"a publish on {FORMATION_TOPIC} from 'anonymous': not in its rights")
    with Probe("127.0.0.1", broker.port, client_id="late") as late:
        late.subscribe(FORMATION_TOPIC)
        assert late.payloads(FORMATION_TOPIC) == []  # nothing retained: the publish was dropped


@pytest.mark.slow
def test_nothing_from_another_host_without_a_login(secured: tuple[EmbeddedBroker, Credentials]) -> None:
    broker, creds = secured
    with other_host() as there:
        anonymous = there.probe(broker.port, client_id="x", publish=FORMATION_TOPIC, payload='{"lan":1}')
        wrong = there.probe(broker.port, client_id="rover-red", user="red", password="guess")
        right = there.probe(broker.port, client_id="rover-red", password=creds.rovers["red"].password, user="red")
    assert (anonymous["accepted"], anonymous["connack"]) == (False, NOT_AUTHORIZED)
    assert (wrong["accepted"], wrong["connack"]) == (False, 4)  # bad user name or password
    assert right["accepted"]


@pytest.mark.slow
def test_an_unauthenticated_connect_with_a_rovers_client_id_leaves_its_session_alone(
    secured: tuple[EmbeddedBroker, Credentials],
) -> None:
    # amqtt alone deletes the session's subscriptions on any clean-session CONNECT with the same id, login or not.
    broker, creds = secured
    with (
        Probe("127.0.0.1", broker.port, client_id="rover-red", **login(creds, "red")) as red,
        Probe("127.0.0.1", broker.port, client_id=f"edge-ips-{EDGE_ID}", **login(creds, "edge")) as edge,
    ):
        red.subscribe(FORMATION_TOPIC)
        for attempt in (
            {"client_id": "rover-red"},
            {"client_id": "rover-red", "user": "red", "password": "guess"},
            {"client_id": "rover-red", **login(creds, "green")},
        ):
            with Probe("127.0.0.1", broker.port, **attempt) as intruder:  # type: ignore[arg-type]
                assert not intruder.accepted
        edge.publish(FORMATION_TOPIC, b'{"still":"subscribed"}', retain=True)
        assert red.wait_payload(FORMATION_TOPIC, b'{"still":"subscribed"}')
        assert red.disconnects == 0


@pytest.mark.slow
def test_a_rover_login_cannot_take_the_edges_client_id(
    secured: tuple[EmbeddedBroker, Credentials],
) -> None:
    broker, creds = secured
    target = BrokerTarget(False, "127.0.0.1", broker.port, username="edge", password=creds.edge.password)
    publisher = MqttPublisher(target, edge_id=EDGE_ID, rovers=ROVERS, reconnect_min_s=0.1, reconnect_max_s=0.2)
    publisher.start()
    try:
        assert publisher.wait_connected(10)
        with Probe("127.0.0.1", broker.port, client_id="watch") as watcher:
            watcher.subscribe(edge_status_topic(EDGE_ID))
            with Probe("127.0.0.1", broker.port, client_id=f"edge-ips-{EDGE_ID}", **login(creds, "red")) as red:
                assert (red.accepted, red.connack_code) == (False, IDENTIFIER_REJECTED)
            states = edge_states_until_marker(publisher, watcher, EDGE_ID)
        assert "offline" not in states  # the edge's last will was never published
        assert publisher.connected and publisher.stats.disconnects == 0
    finally:
        publisher.stop()


@pytest.mark.slow
def test_a_last_will_on_a_topic_the_login_may_not_publish_is_refused_at_connect(
    secured: tuple[EmbeddedBroker, Credentials],
) -> None:
    broker, creds = secured
    will = (FORMATION_TOPIC, b'{"v":1,"seq":1,"kind":"line"}')
    with Probe("127.0.0.1", broker.port, client_id="rover-red", will=will, **login(creds, "red")) as red:
        assert (red.accepted, red.connack_code) == (False, NOT_AUTHORIZED)
    own = (rover_status_topic("red"), b'{"state":"offline"}')
    with Probe("127.0.0.1", broker.port, client_id="rover-red", will=own, **login(creds, "red")) as red:
        assert red.accepted


@pytest.mark.slow
def test_oversized_payloads_are_dropped_and_oversized_packets_disconnect(
    secured: tuple[EmbeddedBroker, Credentials], refusals: Refusals
) -> None:
    broker, creds = secured
    with Probe("127.0.0.1", broker.port, client_id="edge-ips-x", **login(creds, "edge")) as edge:
        edge.publish(FORMATION_TOPIC, b'{"fits":1}', retain=True)
        edge.publish(FORMATION_TOPIC, b"{" + b" " * payload_limit(FORMATION_TOPIC) + b"}", retain=True)
        assert refusals.wait_for(f"a payload of {payload_limit(FORMATION_TOPIC) + 2} bytes on {FORMATION_TOPIC}")
        edge.client.publish(FORMATION_TOPIC, b"x" * (2 << 20), qos=1, retain=True)  # 2 MiB
        assert edge.wait(lambda: edge.disconnects > 0)
    assert refusals.wait_for(f"a packet of {(2 << 20) + 2 + len(FORMATION_TOPIC) + 2} bytes")
    with Probe("127.0.0.1", broker.port, client_id="late") as late:
        late.subscribe(FORMATION_TOPIC)
        assert late.wait(lambda: len(late.received) == 1)
        assert late.payloads(FORMATION_TOPIC) == [b'{"fits":1}']


@pytest.mark.slow
def test_without_logins_it_serves_this_machine_only() -> None:
    with EmbeddedBroker("0.0.0.0", 0) as broker, other_host() as there:
        remote = there.probe(broker.port, client_id="x")
        with Probe("127.0.0.1", broker.port, client_id="local") as local:
            assert local.accepted
    assert (remote["accepted"], remote["connack"]) == (False, NOT_AUTHORIZED)


def _connect_packet(client_id: bytes, user: bytes | None = None, password: bytes | None = None) -> bytes:
    """An MQTT 3.1.1 CONNECT, built by hand so that it can be repeated, cut or sent to a client that resets."""
    flags = 0x02 | (0x80 if user is not None else 0) | (0x40 if password is not None else 0)
    body = b"\x00\x04MQTT\x04" + bytes([flags]) + b"\x00\x3c" + len(client_id).to_bytes(2, "big") + client_id
    for part in (user, password):
        if part is not None:
            body += len(part).to_bytes(2, "big") + part
    return b"\x10" + bytes([len(body)]) + body


def _send_and_reset(port: int, data: bytes) -> None:
    """Send ``data`` and reset the connection at once (SO_LINGER 0): a client gone before the broker closes."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        s.sendall(data)


@pytest.mark.slow
def test_malformed_and_reset_connections_leave_no_traceback_and_a_bounded_log(
    secured: tuple[EmbeddedBroker, Credentials], caplog: pytest.LogCaptureFixture
) -> None:
    """What a script on the network can send: garbage, a PUBLISH before CONNECT, a CONNECT amqtt refuses itself,
    a wrong password, each followed by a reset; and a session of sixty CONNECTs (a protocol violation amqtt logs
    as an ERROR each time). The broker keeps serving, no traceback reaches the log, and amqtt's own lines stay
    within their cap a minute."""
    broker, creds = secured
    caplog.set_level(logging.WARNING)
    for data in (
        bytes(range(256)) * 2,
        b"\x30\x0a\x00\x03a/bhello",  # a PUBLISH first
        _connect_packet(b"x")[:9],  # cut short
        _connect_packet(b"x").replace(b"\x04\x02", b"\x63\x02", 1),  # protocol level 99
        _connect_packet(b"rover-red", b"red", b"wrong"),
    ):
        for _ in range(5):
            _send_and_reset(broker.port, data)
    with socket.create_connection(("127.0.0.1", broker.port), timeout=10) as s:
        s.sendall(_connect_packet(b"anon") * 60 + b"\xc0\x00")  # then a PINGREQ
        answers = b""
        while b"\xd0\x00" not in answers:  # PINGRESP: every CONNECT before it was read (and logged)
            chunk = s.recv(4096)
            assert chunk, "the broker closed the session before answering its PINGREQ"
            answers += chunk
    with Probe("127.0.0.1", broker.port, client_id="rover-red", **login(creds, "red")) as red:
        assert red.accepted
        red.subscribe(FORMATION_TOPIC)
        with Probe("127.0.0.1", broker.port, client_id="edge-ips-x", **login(creds, "edge")) as edge:
            edge.publish(FORMATION_TOPIC, b'{"after":1}')
            assert red.wait(lambda: red.payloads(FORMATION_TOPIC) == [b'{"after":1}'])
    assert not [r for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()]
    assert not [r for r in caplog.records if r.name == "asyncio"]
    amqtt_lines = [r for r in caplog.records if r.name.startswith("amqtt")]
    assert 0 < len(amqtt_lines) <= AMQTT_LINES_PER_MINUTE


# -- the pieces --------------------------------------------------------------------------------------------------
@given(st.integers(0, 3 * MAX_PACKET_BYTES), st.integers(1, 7))
def test_packet_limit_follows_packets_in_any_chunking(length: int, chunk: int) -> None:
    body = bytes(length)
    encoded, value = bytearray(), length
    while True:
        byte, value = value % 128, value // 128
        encoded.append(byte | (0x80 if value else 0))
        if not value:
            break
    stream = bytes([0x30]) + bytes(encoded) + body + bytes([0xC0, 0x00])  # a PUBLISH, then a PINGREQ
    limit = PacketLimit()
    chunks = [stream[i : i + chunk] for i in range(0, len(stream), chunk)]
    if length > MAX_PACKET_BYTES:
        with pytest.raises(PacketTooLarge):
            for piece in chunks:
                limit.feed(piece)
    else:
        for piece in chunks:
            limit.feed(piece)


@pytest.mark.parametrize(
    ("user", "client_id", "allowed"),
    [
        ("red", "rover-red", True),
        ("red", "rover-green", False),
        ("red", "edge-ips-edge-1", False),
        ("red", "anything", False),
        ("edge", "edge-ips-edge-1-dashboard", True),
        ("edge", "rover-red", False),
        ("edge", "laptop", True),
        ("viewer", "edge-ips-edge-1", False),
        ("viewer", "laptop", True),
        (None, "rover-red", False),
        (None, "", True),
    ],
)
def test_client_ids_belong_to_logins(user: str | None, client_id: str, allowed: bool) -> None:
    assert Policy("edge-1", tuple(ROVERS)).may_use_client_id(user, client_id) is allowed


def test_other_host_is_not_this_machines_loopback() -> None:
    with other_host() as there:
        assert isinstance(there, OtherHost) and not there.address.startswith("127.")


def _ip_listing(tmp_path: Path, holds: list[str]) -> str:
    """An ``ip`` program whose ``addr show`` lists ``holds`` (``A.B.C.D/N`` or ``A.B.C.D peer E.F.G.H/32``)."""
    listing = tmp_path / "listing"
    listing.write_text(
        "".join(f"9: vo{i}    inet {a} scope global vo{i}\\       valid_lft forever\n" for i, a in enumerate(holds))
    )
    program = tmp_path / "ip"
    program.write_text(f"#!/bin/sh\ncat {listing}\n")
    program.chmod(0o755)
    return str(program)


def test_a_probe_host_takes_the_subnet_no_interface_holds(tmp_path: Path) -> None:
    # Every /30 of 10.211.0.0/16 held (one as a point-to-point peer address) but 10.211.17.8/30: that one is taken.
    holds = [f"10.211.{n // 64}.{n % 64 * 4 + 1}/30" for n in range(1, 250 * 64) if n not in (17 * 64 + 2, 5)]
    holds.append("10.211.0.21 peer 10.211.0.22/32")
    assert _free_subnet(_ip_listing(tmp_path, holds)) == 17 * 64 + 2
    with pytest.raises(RuntimeError, match="namespaces left behind"):
        _free_subnet(_ip_listing(tmp_path, [*holds, "10.211.17.9/30"]))


def test_a_host_left_behind_takes_no_probe_s_replies() -> None:
    # A namespace a killed run left behind (or a run beside this one) holds its subnet: a new one on the same subnet
    # had its replies routed there, and every probe from it timed out (a CI flake, 1 in 250 runs).
    with other_host() as left, other_host() as there, EmbeddedBroker("0.0.0.0", 0) as broker:
        if there.namespace is not None:  # else both are this machine's own non-loopback address
            assert (
                ipaddress.ip_interface(f"{left.host_address}/30").network
                != ipaddress.ip_interface(f"{there.host_address}/30").network
            )
        for host in (left, there):
            report = host.probe(broker.port, client_id="probe", timeout_s=30)
            assert report["error"] == "" and report["connack"] is not None, report


def test_silent_sockets_from_a_host_keep_neither_this_machine_nor_other_hosts_out(
    secured: tuple[EmbeddedBroker, Credentials],
) -> None:
    # Each STOP of the dashboard and each `edge-ips formation` is a new connection from this machine: a host on
    # the network that holds sockets open without a CONNECT (dropped only after 10 s) must not keep them out.
    broker, creds = secured
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("192.0.2.1", 9))  # no packet is sent: picks this host's outgoing (non-loopback) address
        lan = s.getsockname()[0]
    assert not lan.startswith("127.")
    silent = [
        socket.create_connection((lan, broker.port), source_address=(lan, 0))
        for _ in range(MAX_PENDING_PER_ADDRESS + 1)
    ]
    try:
        silent[-1].settimeout(60)  # a guard only: the broker closes it as soon as it sees it
        assert silent[-1].recv(1) == b""  # one too many from that address: closed at once...
        silent[0].setblocking(False)
        with pytest.raises(BlockingIOError):
            silent[0].recv(1)  # ...while the first still waits for its CONNECT (not the 10 s timeout for all)
        with Probe("127.0.0.1", broker.port, client_id="edge-ips-stop", **login(creds, "edge")) as edge:
            assert edge.accepted
    finally:
        for sock in silent:
            sock.close()


def test_silent_sockets_from_this_machine_do_not_keep_the_dashboards_stop_out(
    secured: tuple[EmbeddedBroker, Credentials], refusals: Refusals
) -> None:
    # A process on the board holding sockets without a CONNECT (each dropped only after 10 s, and opened again)
    # filled this machine's room, and every new connection from here (the dashboard's STOP, `edge-ips formation`)
    # was refused: the oldest silent one now makes room.
    broker, creds = secured
    silent = [socket.create_connection(("127.0.0.1", broker.port)) for _ in range(MAX_PENDING_CONNECTS)]
    try:
        with Probe("127.0.0.1", broker.port, client_id="edge-ips-stop", **login(creds, "edge")) as edge:
            assert edge.accepted
        assert refusals.wait_for("no CONNECT yet, closed to make room for one from 127.0.0.1")  # not a timeout's
        silent[0].settimeout(60)  # a guard only: the broker closed it to make room
        assert silent[0].recv(1) == b""
        silent[-1].setblocking(False)
        with pytest.raises(BlockingIOError):
            silent[-1].recv(1)  # the newest silent one still waits for its CONNECT
    finally:
        for sock in silent:
            sock.close()


def test_a_full_group_closes_its_oldest_silent_socket_and_each_group_has_its_own_room() -> None:
    pending = PendingConnects()
    closed: list[str] = []
    hosts = [f"10.0.0.{i}" for i in range(MAX_PENDING_CONNECTS // MAX_PENDING_PER_ADDRESS)]
    tickets = {}
    for host in hosts:
        for k in range(MAX_PENDING_PER_ADDRESS):
            assert pending.refusal(host) is None
            name = f"{host}#{k}"
            tickets[name] = pending.enter(host, lambda name=name: closed.append(name))[0]
        assert "from that address" in str(pending.refusal(host))  # one host alone: refused
    assert pending.waiting("other hosts") == MAX_PENDING_CONNECTS and closed == []
    for local in ("127.0.0.1", "::1", "::ffff:127.0.0.1"):  # this machine's own clients are counted apart
        assert pending.refusal(local) is None
        assert pending.enter(local, lambda: closed.append("local"))[1] is None
    assert closed == []
    assert pending.refusal("10.0.1.1") is None  # every other host together is at the cap: the oldest makes room
    ticket, evicted = pending.enter("10.0.1.1", lambda: closed.append("rover"))
    assert (evicted, closed) == ("10.0.0.0", ["10.0.0.0#0"]) and pending.evicted == 1
    pending.leave("10.0.0.0", tickets["10.0.0.0#0"])  # the closed socket's handler ends
    assert pending.refusal("10.0.0.0") is None  # that host has room for one again
    pending.leave("10.0.1.1", ticket)  # the newcomer sent its CONNECT
    assert pending.waiting("other hosts") == MAX_PENDING_CONNECTS - 1
