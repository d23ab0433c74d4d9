"""Several boards, one central broker: ``edge-ips broker-config --bridge`` writes both ends of every bridge.

Each board runs its own Mosquitto (its edge-ips publishes to localhost, never blocked by the network); the central
Mosquitto, where the fusers run and the rovers connect, opens one bridge to each board (``connection board-<id>``).
The central one opens them, not the boards, because Mosquitto sets ``TCP_NODELAY`` (``set_tcp_nodelay``) only on
the sockets it accepts, never on a bridge it opens: the detections, the stream that must not wait, go board ->
central, so they leave through a socket the board's broker accepted and are sent at once instead of waiting behind
Nagle's algorithm for the previous segment's ACK (measured: the bridge's p99 fell from 38 to 13 ms).

What crosses each bridge:

* from the board (``in`` at the central): its detections and status (``ips/v1/edge/<id>/detections``,
  ``.../status``) and the statuses of rovers that connected to the board's broker;
* to the board (``out``): the canonical poses, the fusers' statuses and the formation, for rovers and dashboards on
  the board. The formation is commanded at the central broker only: a bridge that comes back sends the board the
  central's retained formation, and never brings an old one back from the board;
* the link's state, retained on ``ips/v1/edge/<id>/bridge`` at the central broker (``1`` up, ``0`` down), which
  the central broker publishes itself (``notifications_local_only``), so ``doctor`` sees every link.

Nothing stale crosses a bridge that comes back: ``cleansession true`` (the board forgets the central's session when
the link drops, so it queues nothing for it; the central drops what it had queued for the board when it reconnects),
detections at QoS 0, and the fuser drops anything older than its age limit by capture time anyway.

Logins at the central broker: each fuser (``fuser-...``: poses, its status, the lease, and the formation for its
retained stop on every connection), each rover, the operators' ``edge`` login (formation commands, ``doctor``) and a
read-only ``viewer``. At each board: its ``edge`` (the board's edge-ips), its rovers, the
``viewer``, and ``central``, the central broker's bridge, which may read the board's detections, status and rover
statuses and write the poses, the fusers' statuses and the formation, nothing else (its own password per board).
Client id = user name on the network listeners, so a login cannot take another's session. With ``tls``, each board
gets a TLS listener that requires the client certificate (the link now arrives at the board) and the central's
bridge to it uses TLS; the central broker gets one as well, for fusers and operators on other machines.
"""

from __future__ import annotations

import json
import re
import shutil
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from edge.board_messages import (
    DETECTIONS_MAX_BYTES,
    FUSER_STATUS_MAX_BYTES,
    FUSER_STATUS_WILDCARD,
    detections_topic,
    fuser_status_topic,
)
from edge.broker.access import (
    ALL_TOPICS,
    VIEWER_RIGHTS,
    VIEWER_USER,
    Rights,
    check_names,
    rights_acl_text,
    rover_rights,
)
from edge.broker.credentials import new_password
from edge.broker.mosquitto import (
    LOCAL_PASSWD,
    NETWORK_MAX_CONNECTIONS,
    TLS_MAX_CONNECTIONS,
    login_lines,
    write_password_file,
)
from edge.broker.tls import tls_listener_lines, write_tls_files
from edge.errors import BrokerError
from edge.fusion.lease import LEASE_TOPIC
from edge.messages import (
    FORMATION_TOPIC,
    POSE_WILDCARD,
    ROVER_STATUS_WILDCARD,
    TOPIC_PREFIX,
    edge_status_topic,
)
from edge.private_files import private_dir, write_private

EDGE_USER = "edge"
CENTRAL_USER = "central"  # the central broker's bridge, at each board's broker
CENTRAL_PORT = 1883
CENTRAL_TLS_PORT = 8883
LOCAL_PORT = 1884
# the largest message of several boards: a fuser's status (boards, rovers); detections are smaller
MESSAGE_LIMIT_BYTES = max(DETECTIONS_MAX_BYTES, FUSER_STATUS_MAX_BYTES)
PACKET_LIMIT_BYTES = MESSAGE_LIMIT_BYTES + 1024
BRIDGE_TLS_FILES = ("ca.crt", "client.crt", "client.key")  # a board's, copied to the central for its bridge


def board_topics(edge_id: str) -> str:
    return f"{TOPIC_PREFIX}/edge/{edge_id}/#"


def bridge_state_topic(edge_id: str) -> str:
    """Retained ``1``/``0`` at the central broker: its bridge to the board is up or down."""
    return f"{TOPIC_PREFIX}/edge/{edge_id}/bridge"


@dataclass(frozen=True)
class BoardAddress:
    """How the central broker reaches a board's broker; ``port`` None: the board's network (or TLS) listener."""

    host: str
    port: int | None = None

    def address(self, default_port: int) -> str:
        # Mosquitto's `address` takes an IPv6 address unbracketed, always with its port
        return f"{self.host}:{self.port if self.port is not None else default_port}"


_BOARD_RE = re.compile(r"^(?P<id>[^=]+)=(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[A-Za-z0-9.-]+))(?::(?P<port>\d+))?$")


def parse_board(text: str) -> tuple[str, BoardAddress]:
    """``ID=HOST[:PORT]`` (``cam1=10.0.0.21``, ``cam2=cam2.lab:1883``, ``cam3=[fd00::3]:1883``) -> id, address."""
    match = _BOARD_RE.match(text.strip())
    if match is None:
        raise BrokerError(f"--board {text!r}: write ID=HOST or ID=HOST:PORT (e.g. cam1=10.0.0.21)")
    port = match["port"]
    if port is not None and not 1 <= int(port) <= 65535:
        raise BrokerError(f"--board {text!r}: port {port} is not in 1-65535")
    return match["id"], BoardAddress(match["v6"] or match["host"], int(port) if port is not None else None)


def central_rights(fusers: Sequence[str], rovers: Sequence[str]) -> dict[str, Rights]:
    """Who may do what on the central broker (its bridges to the boards are its own, not logins). A fuser publishes
    the formation too: its retained stop on every connection (:mod:`edge.fusion.service`), for a central broker that
    crashed comes back with the formation it last saved."""
    table = {EDGE_USER: Rights(publish=(FORMATION_TOPIC,), read=(ALL_TOPICS,))}
    for fuser in fusers:
        table[fuser] = Rights(
            publish=(POSE_WILDCARD, fuser_status_topic(fuser), LEASE_TOPIC, FORMATION_TOPIC), read=(ALL_TOPICS,)
        )
    table.update({rover: rover_rights(rover) for rover in rovers})
    table[VIEWER_USER] = VIEWER_RIGHTS
    return table


def board_rights(board: str, rovers: Sequence[str]) -> dict[str, Rights]:
    """Who may do what on a board's own broker: its edge (the board's publisher, dashboard, tools), the central
    broker's bridge (what crosses the bridge and nothing else), its rovers, the viewer."""
    table = {
        EDGE_USER: Rights(publish=(board_topics(board),), read=(ALL_TOPICS,)),
        CENTRAL_USER: Rights(
            publish=(POSE_WILDCARD, FUSER_STATUS_WILDCARD, FORMATION_TOPIC),
            read=(detections_topic(board), edge_status_topic(board), ROVER_STATUS_WILDCARD),
        ),
    }
    table.update({rover: rover_rights(rover) for rover in rovers})
    table[VIEWER_USER] = VIEWER_RIGHTS
    return table


@dataclass(frozen=True)
class BridgeFiles:
    central: Path
    boards: dict[str, Path]

    def all(self) -> list[Path]:
        out = sorted(p for p in self.central.rglob("*") if p.is_file())
        for where in self.boards.values():
            out += sorted(where.iterdir())
        return out


def _limits() -> list[str]:
    return [
        "# Each listener names the logins it takes (the loopback one the edge's only); one ACL.",
        "per_listener_settings true",
        "# Several boards' messages: detections (up to 64 rovers) and the fusers' statuses are the largest.",
        f"max_packet_size {PACKET_LIMIT_BYTES}",
        f"message_size_limit {MESSAGE_LIMIT_BYTES}",
        "# Send each small message at once on the sockets this broker accepts (Mosquitto cannot set it on a bridge",
        "# it opens: that is why the central broker opens the bridges, and the detections leave the boards on",
        "# sockets the boards' brokers accepted).",
        "set_tcp_nodelay true",
    ]


def _listeners(where: Path, port: int, local_port: int, tls_port: int | None, who: str) -> list[str]:
    lines = [
        "# The edge's own tools on this machine with the edge login (the only one taken here: a rover's, read out",
        "# of its flash, would take their sessions), each with its own client id.",
        f"listener {local_port} 127.0.0.1",
        *login_lines(where, LOCAL_PASSWD),
        "",
        f"# {who}: a client's id is its user name; at most so many sockets (file descriptors left for the edge's).",
        f"listener {port} 0.0.0.0",
        f"max_connections {NETWORK_MAX_CONNECTIONS}",
        "use_username_as_clientid true",
        *login_lines(where, "passwd"),
        "",
    ]
    if tls_port is not None:
        lines += [
            "# TLS: only clients holding client.crt (signed by ca.crt) connect.",
            *[
                line
                for line in tls_listener_lines(
                    tls_port, "0.0.0.0", where, clientid_from_username=True, max_connections=TLS_MAX_CONNECTIONS
                )
                if line
            ],
            *login_lines(where, "passwd"),
            "",
        ]
    return lines


def _connection(board: str, address: str, password: str, tls_dir: Path | None) -> list[str]:
    """The central broker's bridge to one board: what flows each way, and its state at the central."""
    lines = [
        f"connection board-{board}",
        f"address {address}",
        f"remote_username {CENTRAL_USER}",
        f"remote_password {password}",
        f"remote_clientid {CENTRAL_USER}",
        f"local_clientid bridge-{board}",
        # the board forgets this session when the link drops, so nothing is queued for a replay
        "cleansession true",
        "keepalive_interval 5",
        "restart_timeout 1 10",
        # nothing to unsubscribe on a clean session
        "bridge_attempt_unsubscribe false",
        # the board sees a bridge, so a message never comes back over the link it arrived by
        "try_private true",
        "notifications true",
        "notifications_local_only true",
        f"notification_topic {bridge_state_topic(board)}",
        f"topic {detections_topic(board)} in 1",
        f"topic {edge_status_topic(board)} in 1",
        f"topic {ROVER_STATUS_WILDCARD} in 1",
        f"topic {POSE_WILDCARD} out 0",
        f"topic {FUSER_STATUS_WILDCARD} out 1",
        f"topic {FORMATION_TOPIC} out 1",
    ]
    if tls_dir is not None:
        lines += [
            f"bridge_cafile {tls_dir / 'ca.crt'}",
            f"bridge_certfile {tls_dir / 'client.crt'}",
            f"bridge_keyfile {tls_dir / 'client.key'}",
            "bridge_tls_version tlsv1.2",
        ]
    return [*lines, ""]


def _central_conf(
    where: Path,
    *,
    port: int,
    local_port: int,
    tls_port: int | None,
    boards: Mapping[str, BoardAddress],
    passwords: Mapping[str, str],
) -> str:
    lines = [
        f"# Central Mosquitto of several edge-ips boards ({', '.join(boards)}), written by",
        "# `edge-ips broker-config --bridge`. The fusers (edge-ips fuse) and the rovers connect here; this broker",
        "# opens one bridge to each board. Holds the bridges' passwords: keep it secret (mode 600).",
        *_limits(),
        "",
        *_listeners(where, port, local_port, tls_port, "Rovers, fusers and the rest of the network"),
    ]
    default_port = tls_port if tls_port is not None else port
    for board, address in boards.items():
        tls_dir = where / f"bridge-{board}" if tls_port is not None else None
        lines += _connection(board, address.address(default_port), passwords[board], tls_dir)
    return "\n".join(lines)


def _board_conf(board: str, where: Path, *, local_port: int, port: int, tls_port: int | None) -> str:
    lines = [
        f"# Mosquitto of board {board!r}; the central broker opens its bridge to it (login {CENTRAL_USER!r}).",
        "# Written by `edge-ips broker-config --bridge`. edge-ips on this board: broker.url =",
        f'# mqtt://edge@localhost:{local_port}, edge.publish = "detections".',
        *_limits(),
        "",
        *_listeners(where, port, local_port, tls_port, "The central broker's bridge, rovers"),
    ]
    return "\n".join(lines)


def _credentials(title: str, logins: Mapping[str, Mapping[str, str]]) -> str:
    lines = [
        f"# {title}",
        "# Clear-text logins written by `edge-ips broker-config --bridge`. Keep secret (mode 600).",
        "",
    ]
    for table, users in logins.items():
        for user, password in users.items():
            # [edge] and [viewer] as every credentials file has them (read_credentials reads this one too), the
            # rest grouped: [rovers.<id>], [fusers.<id>]
            name = table if table in SINGLE_LOGINS else f"{table}.{user}"
            lines += [f"[{name}]", f"username = {json.dumps(user)}", f"password = {json.dumps(password)}", ""]
    return "\n".join(lines)


SINGLE_LOGINS = ("edge", "viewer")  # one login each, a table of its own in credentials.toml


def read_logins(path: Path) -> dict[str, dict[str, str]]:
    """A credentials.toml that :func:`write_bridge_configs` wrote, as ``{table: {user: password}}`` (``[edge]`` ->
    ``{"edge": {"edge": ...}}``, ``[fusers.fuser-a]`` -> ``{"fusers": {"fuser-a": ...}}``)."""
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    return {
        table: {users["username"]: users["password"]}
        if table in SINGLE_LOGINS
        else {user: login["password"] for user, login in users.items()}
        for table, users in data.items()
    }


def _check(boards: Mapping[str, BoardAddress], fusers: Sequence[str], rovers: Sequence[str], ports: list[int]) -> None:
    if len(boards) < 1:
        raise BrokerError("--bridge needs the boards and how the central broker reaches them (--board cam1=HOST)")
    check_names(EDGE_USER, list(boards))
    check_names(EDGE_USER, [CENTRAL_USER, *fusers, *rovers])
    if "central" in boards:
        raise BrokerError("a board may not be called 'central' (the central broker's directory)")
    if not all(f.startswith("fuser") for f in fusers):
        raise BrokerError("fuser logins start with 'fuser' (fuser-a, fuser-b)")
    if len(set(ports)) != len(ports):
        raise BrokerError(f"listener ports must differ: {', '.join(map(str, ports))}")


def write_bridge_configs(
    out_dir: Path,
    *,
    boards: Mapping[str, BoardAddress],
    rovers: Sequence[str],
    fusers: Sequence[str] = ("fuser-a", "fuser-b"),
    port: int = CENTRAL_PORT,
    local_port: int = LOCAL_PORT,
    tls_port: int | None = None,
    tls_names: Sequence[str] = (),
    install_dir: Path | None = None,
    force: bool = False,
) -> BridgeFiles:
    """``out_dir/central`` (the central broker, with one bridge to each board) and ``out_dir/<board>`` for each
    board, with random passwords.

    ``boards``: board id -> how the central broker reaches the board's broker; ``tls_names``: how fusers and
    operators on other machines reach the central broker (its TLS listener); ``install_dir``: where each directory
    will live on its machine (``<install_dir>/central``, ``<install_dir>/<board>``; default: ``out_dir``'s)."""
    _check(boards, fusers, rovers, [port, local_port, *([tls_port] if tls_port is not None else [])])
    dirs = {"central": out_dir / "central", **{b: out_dir / b for b in boards}}
    existing = [str(d) for d in dirs.values() if d.exists() and any(d.iterdir())]
    if existing and not force:
        raise BrokerError(f"{', '.join(existing)} already exist (use --force to overwrite)")
    base = install_dir if install_dir is not None else out_dir.resolve()
    for d in dirs.values():
        private_dir(d)
    passwords = {user: new_password() for user in [EDGE_USER, *fusers, *rovers, VIEWER_USER]}
    bridge_passwords = {board: new_password() for board in boards}  # the central's login at each board
    central = dirs["central"]
    tls = tls_port is not None
    if tls:
        write_tls_files(central, tls_names)
    write_password_file(central / "passwd", passwords)
    write_password_file(central / LOCAL_PASSWD, {EDGE_USER: passwords[EDGE_USER]})
    write_private(central / "acl", rights_acl_text(central_rights(fusers, rovers)), mode=0o640)
    write_private(
        central / "mosquitto.conf",
        _central_conf(
            base / "central",
            port=port,
            local_port=local_port,
            tls_port=tls_port,
            boards=boards,
            passwords=bridge_passwords,
        ),
    )  # mode 600: it holds the bridges' passwords
    write_private(
        central / "credentials.toml",
        _credentials(
            "Central broker logins: [edge] for the operators' tools, [fusers.*] for edge-ips fuse, [rovers.*] for"
            " the firmware, [viewer] read-only.",
            {
                "edge": {EDGE_USER: passwords[EDGE_USER]},
                "fusers": {f: passwords[f] for f in fusers},
                "rovers": {r: passwords[r] for r in rovers},
                "viewer": {VIEWER_USER: passwords[VIEWER_USER]},
            },
        ),
    )
    board_dirs = {}
    for board, address in boards.items():
        where = dirs[board]
        if tls:
            # the board's own CA and server certificate (for the name the central reaches it by); the central's
            # bridge holds the board's CA and client certificate
            write_tls_files(where, [address.host])
            bridge_tls = private_dir(central / f"bridge-{board}")
            for name in BRIDGE_TLS_FILES:
                shutil.copyfile(where / name, bridge_tls / name)
                (bridge_tls / name).chmod(0o600 if name.endswith(".key") else 0o644)
        local = {
            EDGE_USER: new_password(),
            CENTRAL_USER: bridge_passwords[board],
            **{r: passwords[r] for r in rovers},
            VIEWER_USER: passwords[VIEWER_USER],
        }
        write_password_file(where / "passwd", local)
        write_password_file(where / LOCAL_PASSWD, {EDGE_USER: local[EDGE_USER]})
        write_private(where / "acl", rights_acl_text(board_rights(board, rovers)), mode=0o640)
        write_private(
            where / "mosquitto.conf",
            _board_conf(board, base / board, local_port=local_port, port=port, tls_port=tls_port),
            mode=0o644,
        )
        write_private(
            where / "credentials.toml",
            _credentials(
                f"Board {board}'s broker: [edge] for edge-ips on the board, [rovers.*] for rovers that connect here.",
                {"edge": {EDGE_USER: local[EDGE_USER]}, "rovers": {r: local[r] for r in rovers}},
            ),
        )
        board_dirs[board] = where
    return BridgeFiles(central, board_dirs)
