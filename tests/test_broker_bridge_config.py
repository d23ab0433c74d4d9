"""`edge-ips broker-config --bridge`: the central broker opens one bridge to each board; the boards' logins for it
have the least rights (enforced by a real Mosquitto); secrets are private; with --tls each board has its own CA."""

from __future__ import annotations

import re
import stat
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner
from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric import ec

from edge.broker.access import topic_matches, verify_mosquitto_hash
from edge.broker.bridge import BoardAddress, parse_board, write_bridge_configs
from edge.cli import main
from edge.errors import BrokerError
from edge.messages import FormationV1
from tests.support.mosquitto import Mosquitto
from tests.support.probe import Probe
from tests.support.runtime import MqttRecorder

BOARDS = {"cam1": BoardAddress("10.0.0.21"), "cam2": BoardAddress("cam2.lab", 1999)}


def connections(conf: str) -> dict[str, dict[str, list[str]]]:
    """The central's ``connection`` blocks: board -> option -> values (in file order)."""
    out: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for line in conf.splitlines():
        if line.startswith("connection board-"):
            current = out.setdefault(line.removeprefix("connection board-"), {})
        elif current is not None and line and not line.startswith("#"):
            key, _, value = line.partition(" ")
            current.setdefault(key, []).append(value)
    return out


def acl_users(text: str) -> dict[str, set[str]]:
    users: dict[str, set[str]] = {}
    user = ""
    for line in text.splitlines():
        if line.startswith("user "):
            user = line.split()[1]
            users[user] = set()
        elif line.startswith("topic "):
            users[user].add(line.removeprefix("topic "))
    return users


@pytest.mark.parametrize(
    ("text", "board", "address"),
    [
        ("cam1=10.0.0.21", "cam1", BoardAddress("10.0.0.21")),
        ("cam2=cam2.lab:1999", "cam2", BoardAddress("cam2.lab", 1999)),
        (" cam-3=[fd00::3]:1883 ", "cam-3", BoardAddress("fd00::3", 1883)),
    ],
)
def test_a_board_is_its_id_and_how_the_central_reaches_it(text: str, board: str, address: BoardAddress) -> None:
    assert parse_board(text) == (board, address)


@pytest.mark.parametrize(
    "text", ["cam1", "cam1=", "=10.0.0.1", "cam1=10.0.0.1:", "cam1=10.0.0.1:70000", "cam1=a b", "cam1=h:1:2"]
)
def test_a_malformed_board_is_refused(text: str) -> None:
    with pytest.raises(BrokerError, match="--board"):
        parse_board(text)


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--bridge"], "--board cam1=HOST"),
        (["--bridge", "--board", "cam1"], "ID=HOST"),
        (["--bridge", "--board", "cam1=h:0"], "1-65535"),
        (["--bridge", "--board", "Cam1=h"], "Cam1"),
        (["--bridge", "--board", "central=h"], "central"),
        (["--bridge", "--board", "cam1=a", "--board", "cam1=b"], "each board id once"),
        (["--board", "cam1=a"], "--board goes with --bridge"),
    ],
)
def test_broker_config_bridge_says_what_is_wrong_in_one_line(tmp_path: Path, args: list[str], says: str) -> None:
    result = CliRunner().invoke(main, ["broker-config", *args, "--rovers", "r1", "--out", str(tmp_path / "b")])
    assert result.exit_code == 2, result.output
    assert says in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()[-1]) < 200


def test_the_central_opens_one_bridge_per_board_with_its_own_login_there(tmp_path: Path) -> None:
    files = write_bridge_configs(tmp_path, boards=BOARDS, rovers=["r1"], port=1883)
    conf = (files.central / "mosquitto.conf").read_text()
    bridges = connections(conf)
    assert set(bridges) == {"cam1", "cam2"}
    assert bridges["cam1"]["address"] == ["10.0.0.21:1883"]  # the board's network listener by default
    assert bridges["cam2"]["address"] == ["cam2.lab:1999"]
    for board, bridge in bridges.items():
        assert bridge["remote_username"] == ["central"]
        # the password the central's bridge uses is the one the board's broker checks
        hashed = dict(line.split(":", 1) for line in (files.boards[board] / "passwd").read_text().splitlines())
        assert verify_mosquitto_hash(bridge["remote_password"][0], hashed["central"])
        assert set(bridge["topic"]) == {
            f"ips/v1/edge/{board}/detections in 1",
            f"ips/v1/edge/{board}/status in 1",
            "ips/v2/rovers/+/status in 1",
            "ips/v1/rovers/+/pose out 0",
            "ips/v1/fuser/+/status out 1",
            "ips/v1/formation out 1",
        }
        # nothing queued for a replay; the link's state published by the central broker itself
        assert bridge["cleansession"] == ["true"] and bridge["notifications_local_only"] == ["true"]
        assert bridge["notification_topic"] == [f"ips/v1/edge/{board}/bridge"]
        assert bridge["local_clientid"] == [f"bridge-{board}"]  # unique at the central broker
        assert "connection " not in (files.boards[board] / "mosquitto.conf").read_text()  # a board opens nothing
    assert bridges["cam1"]["remote_password"] != bridges["cam2"]["remote_password"]
    assert "set_tcp_nodelay true" in (files.boards["cam1"] / "mosquitto.conf").read_text()
    # no board logs in at the central broker any more
    assert set(acl_users((files.central / "acl").read_text())) == {"edge", "fuser-a", "fuser-b", "r1", "viewer"}


def test_the_centrals_login_at_a_board_has_the_least_rights(tmp_path: Path) -> None:
    files = write_bridge_configs(tmp_path, boards=BOARDS, rovers=["r1"])
    users = acl_users((files.boards["cam1"] / "acl").read_text())
    assert users["central"] == {
        "read ips/v1/edge/cam1/detections",
        "read ips/v1/edge/cam1/status",
        "read ips/v2/rovers/+/status",
        "write ips/v1/rovers/+/pose",
        "write ips/v1/fuser/+/status",
        "write ips/v1/formation",
    }
    # the formation is commanded at the central broker: a board's edge cannot publish one the others never see
    edge_writes = [t.split()[1] for t in users["edge"] if t.startswith(("write", "readwrite"))]
    assert not any(topic_matches("ips/v1/formation", t) for t in edge_writes)
    assert any(topic_matches("ips/v1/edge/cam1/detections", t) for t in edge_writes)
    assert not any(topic_matches("ips/v1/edge/cam2/detections", t) for t in edge_writes)


def test_secrets_are_private_and_the_rest_readable(tmp_path: Path) -> None:
    files = write_bridge_configs(tmp_path, boards=BOARDS, rovers=["r1"], tls_port=8883, tls_names=["central.lab"])
    modes = {p.relative_to(tmp_path).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in files.all()}
    assert modes["central/mosquitto.conf"] == 0o600  # it holds the bridges' passwords
    assert modes["cam1/mosquitto.conf"] == 0o644
    for where in ("central", "cam1", "cam2"):
        assert modes[f"{where}/passwd"] == 0o600 and modes[f"{where}/credentials.toml"] == 0o600
        assert modes[f"{where}/acl"] == 0o640
        assert modes[f"{where}/server.key"] == 0o600 and modes[f"{where}/client.key"] == 0o600
    assert modes["central/bridge-cam1/client.key"] == 0o600 and modes["central/bridge-cam1/ca.crt"] == 0o644
    assert stat.S_IMODE((tmp_path / "central").stat().st_mode) == 0o700
    # the central broker's conf is the only file with the bridges' passwords; the boards' edge logins are apart
    board_logins = tomllib.loads((tmp_path / "cam1" / "credentials.toml").read_text())
    assert set(board_logins) == {"edge", "rovers"}


def test_with_tls_each_board_has_its_own_ca_and_the_central_bridge_holds_its_client_certificate(
    tmp_path: Path,
) -> None:
    files = write_bridge_configs(tmp_path, boards=BOARDS, rovers=[], tls_port=8883, tls_names=["central.lab"])
    bridges = connections((files.central / "mosquitto.conf").read_text())
    assert bridges["cam1"]["address"] == ["10.0.0.21:8883"]  # the board's TLS listener
    assert bridges["cam2"]["address"] == ["cam2.lab:1999"]
    for board in BOARDS:
        conf = (files.boards[board] / "mosquitto.conf").read_text()
        assert re.search(
            r"^listener 8883 0\.0\.0\.0\nmax_connections 64\nuse_username_as_clientid true\ncafile ", conf, re.M
        )
        assert "require_certificate true" in conf
        assert bridges[board]["bridge_certfile"] == [
            str(tmp_path.resolve() / "central" / f"bridge-{board}" / "client.crt")
        ]

    def cert(path: Path) -> x509.Certificate:
        return x509.load_pem_x509_certificate(path.read_bytes())

    def signed_by(child: x509.Certificate, ca: x509.Certificate) -> bool:
        try:
            child.verify_directly_issued_by(ca)
            return True
        except (ValueError, InvalidSignature):  # another issuer, another key
            return False

    server = cert(tmp_path / "cam1" / "server.crt")
    names = server.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(ip) for ip in names.get_values_for_type(x509.IPAddress)] == ["10.0.0.21"]
    cam2_names = cert(tmp_path / "cam2" / "server.crt").extensions.get_extension_for_class(x509.SubjectAlternativeName)
    assert cam2_names.value.get_values_for_type(x509.DNSName) == ["cam2.lab"]
    cam1_ca, cam2_ca = cert(tmp_path / "cam1" / "ca.crt"), cert(tmp_path / "cam2" / "ca.crt")
    assert signed_by(cert(tmp_path / "central" / "bridge-cam1" / "client.crt"), cam1_ca)
    assert not signed_by(cert(tmp_path / "central" / "bridge-cam2" / "client.crt"), cam1_ca)
    assert signed_by(server, cam1_ca) and not signed_by(server, cam2_ca)
    assert isinstance(cam1_ca.public_key(), ec.EllipticCurvePublicKey)


@pytest.mark.slow
def test_a_real_board_broker_lets_the_centrals_login_read_and_write_only_what_crosses_the_bridge(
    tmp_path: Path,
) -> None:
    files = write_bridge_configs(tmp_path / "brokers", boards=BOARDS, rovers=["r1"])
    password = connections((files.central / "mosquitto.conf").read_text())["cam1"]["remote_password"][0]
    edge = tomllib.loads((files.boards["cam1"] / "credentials.toml").read_text())["edge"]["password"]
    with Mosquitto(tmp_path / "run", conf_path=files.boards["cam1"] / "mosquitto.conf") as board:
        network = board.ports[1883]
        topics = ("ips/v1/#", "ips/v2/#")
        with (
            MqttRecorder("127.0.0.1", network, topics, username="central", password=password) as central,
            MqttRecorder("127.0.0.1", board.port, topics, username="edge", password=edge) as local,
        ):
            assert central.wait_subscribed() and local.wait_subscribed()
            for topic in ("ips/v1/edge/cam1/detections", "ips/v1/edge/cam1/status", "ips/v1/edge/cam1/other"):
                local.client.publish(topic, b"from the board", qos=1)
            central.client.publish("ips/v1/edge/cam1/detections", b"forged", qos=1)  # denied: not the board's
            central.client.publish("ips/v1/rovers/r1/pose", b"a pose", qos=1)
            assert local.wait_for(lambda msgs: any(m.topic == "ips/v1/rovers/r1/pose" for m in msgs), 30.0)
            # the last message, after all the others from the board (a broker keeps each connection's order)
            local.client.publish("ips/v1/edge/cam1/status", b"last", qos=1)
            assert central.wait_for(lambda msgs: any(m.payload == b"last" for m in msgs), 30.0)
            assert local.wait_for(lambda msgs: any(m.payload == b"last" for m in msgs), 30.0)
    # it reads the board's detections and status, not the rest of the board's topics, nor the poses it writes
    assert [m.topic for m in central.messages] == [
        "ips/v1/edge/cam1/detections",
        "ips/v1/edge/cam1/status",
        "ips/v1/edge/cam1/status",
    ]
    assert not [m for m in local.messages if m.payload == b"forged"]


@pytest.mark.slow
@pytest.mark.parametrize("where", ["central", "cam1"])
def test_only_the_edge_login_connects_to_the_loopback_listener_where_clients_keep_their_ids(
    tmp_path: Path, where: str
) -> None:
    files = write_bridge_configs(tmp_path / "brokers", boards=BOARDS, rovers=["r1"])
    directory = files.central if where == "central" else files.boards[where]
    logins = tomllib.loads((directory / "credentials.toml").read_text())
    with Mosquitto(tmp_path / "run", conf_path=directory / "mosquitto.conf") as broker:
        edge_id = "edge-ips-cam1"  # what edge-ips there uses; kept on this listener, so a rover must not get in
        with Probe("127.0.0.1", broker.port, client_id=edge_id, user="edge", password=logins["edge"]["password"]) as e:
            assert e.accepted
        rover = logins["rovers"]["r1"]
        with Probe("127.0.0.1", broker.port, client_id=edge_id, user="r1", password=rover["password"]) as r1:
            assert not r1.accepted
        with Probe("127.0.0.1", broker.ports[1883], client_id="x", user="r1", password=rover["password"]) as r1:
            assert r1.accepted  # its own listener


@pytest.mark.slow
def test_a_formation_a_boards_broker_drops_is_an_error_not_a_command_sent(tmp_path: Path) -> None:
    """A board's `edge` login may not publish the formation on its broker (commands go to the central one). Mosquitto
    (MQTT 3.1.1) still acknowledges the publish and drops it; `edge-ips formation` and the dashboard read the
    retained command back and say so, instead of reporting a STOP that went nowhere. The central's `edge` login
    commands as before."""
    from edge.commands import build_formation, send_formation
    from edge.config import parse_broker_url
    from edge.errors import BrokerError

    files = write_bridge_configs(tmp_path / "brokers", boards=BOARDS, rovers=["r1"])
    board_edge = tomllib.loads((files.boards["cam1"] / "credentials.toml").read_text())["edge"]["password"]
    central_edge = tomllib.loads((files.central / "credentials.toml").read_text())["edge"]["password"]

    def stop(seq: int) -> FormationV1:
        return build_formation("stop", [], seq=seq)

    with Mosquitto(tmp_path / "run", conf_path=files.boards["cam1"] / "mosquitto.conf") as board:
        target = parse_broker_url(f"mqtt://edge:{board_edge}@127.0.0.1:{board.port}")
        with pytest.raises(BrokerError, match=r"did not take it.*central broker"):
            send_formation(target, stop, timeout_s=2.0)
    with Mosquitto(tmp_path / "run-central", conf_path=files.central / "mosquitto.conf") as central:
        target = parse_broker_url(f"mqtt://edge:{central_edge}@127.0.0.1:{central.port}")
        assert send_formation(target, stop).kind == "stop"
        assert send_formation(target, stop).seq == 2  # read back, and the next one follows it


@pytest.mark.slow
def test_at_the_central_broker_each_fuser_may_publish_its_stop_and_the_viewer_may_not(tmp_path: Path) -> None:
    """A fuser publishes a retained stop on every connection (a crashed central broker brings back an older
    formation): its login may write the formation at the central broker, with the ACL written there; the viewer's
    may not (Mosquitto acknowledges and drops it: read back, an error)."""
    from edge.commands import build_formation, send_formation
    from edge.config import BrokerTarget

    files = write_bridge_configs(tmp_path / "brokers", boards=BOARDS, rovers=["r1"])
    logins = tomllib.loads((files.central / "credentials.toml").read_text())

    def stop(seq: int) -> FormationV1:
        return build_formation("stop", [], seq=seq)

    with Mosquitto(tmp_path / "run", conf_path=files.central / "mosquitto.conf") as central:

        def login(table: dict[str, str]) -> BrokerTarget:
            return BrokerTarget(
                embedded=False,
                host="127.0.0.1",
                port=central.ports[1883],  # the network listener, where fusers connect
                username=table["username"],
                password=table["password"],
            )

        assert [send_formation(login(logins["fusers"][f]), stop).seq for f in ("fuser-a", "fuser-b")] == [1, 2]
        with pytest.raises(BrokerError, match="did not take it"):
            send_formation(login(logins["viewer"]), stop, timeout_s=2.0)
