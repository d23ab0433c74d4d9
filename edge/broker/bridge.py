"""Several boards, one central broker: ``edge-ips broker-config --bridge`` writes both ends of every bridge.

Each board runs its own Mosquitto (its edge-ips publishes to localhost, never blocked by the network) bridged to a
central Mosquitto, where the fusers run and the rovers connect:

* out of each board (``out``): its detections and status, ``ips/v1/edge/<id>/#``, and the statuses of rovers that
  connected to the board's broker;
* into each board (``in``): the canonical poses and the fusers' statuses, for rovers and dashboards on the board;
* both ways: the formation command (Mosquitto's bridge does not echo a message back to the broker it came from);
* the bridge's own state, retained on ``ips/v1/edge/<id>/bridge`` (``1`` up, ``0`` down: the board's broker sets
  it, the central one publishes the bridge's last will when the link dies), so ``doctor`` sees every link.

Detections cross the bridge at QoS 0: a bridge that drops loses them instead of queueing them, and the fuser drops
anything older than its age limit by capture time anyway, so a bridge that comes back replays nothing stale.

Logins at the central broker: each board's bridge (user = the board's id), each fuser (``fuser-...``), each rover,
the operators' ``edge`` login (formation commands, ``doctor``) and a read-only ``viewer``. Client id = user name on
the network listeners, so a login cannot take another's session; the operators' tools use the loopback listener.
With ``tls``, the central broker gets a TLS listener that requires the client certificate, and the bridges (the
link that leaves each board) use it.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from edge.board_messages import DETECTIONS_MAX_BYTES, FUSER_STATUS_MAX_BYTES, FUSER_STATUS_WILDCARD, fuser_status_topic
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
from edge.broker.mosquitto import write_password_file
from edge.broker.tls import write_tls_files
from edge.errors import BrokerError
from edge.fusion.lease import LEASE_TOPIC
from edge.messages import FORMATION_TOPIC, POSE_WILDCARD, TOPIC_PREFIX, rover_status_topic
from edge.private_files import private_dir, write_private

EDGE_USER = "edge"
CENTRAL_PORT = 1883
CENTRAL_TLS_PORT = 8883
LOCAL_PORT = 1884
# the largest message of several boards: a fuser's status (boards, rovers); detections are smaller
MESSAGE_LIMIT_BYTES = max(DETECTIONS_MAX_BYTES, FUSER_STATUS_MAX_BYTES)
PACKET_LIMIT_BYTES = MESSAGE_LIMIT_BYTES + 1024


def board_topics(edge_id: str) -> str:
    return f"{TOPIC_PREFIX}/edge/{edge_id}/#"


def bridge_state_topic(edge_id: str) -> str:
    """Retained ``1``/``0``: the board's bridge to the central broker is up or down."""
    return f"{TOPIC_PREFIX}/edge/{edge_id}/bridge"


def central_rights(boards: Sequence[str], fusers: Sequence[str], rovers: Sequence[str]) -> dict[str, Rights]:
    """Who may do what on the central broker."""
    rover_status = rover_status_topic("+")
    table = {EDGE_USER: Rights(publish=(FORMATION_TOPIC,), read=(ALL_TOPICS,))}
    for board in boards:
        table[board] = Rights(
            publish=(board_topics(board), rover_status, FORMATION_TOPIC),
            read=(POSE_WILDCARD, FORMATION_TOPIC, FUSER_STATUS_WILDCARD),
        )
    for fuser in fusers:
        table[fuser] = Rights(publish=(POSE_WILDCARD, fuser_status_topic(fuser), LEASE_TOPIC), read=(ALL_TOPICS,))
    table.update({rover: rover_rights(rover) for rover in rovers})
    table[VIEWER_USER] = VIEWER_RIGHTS
    return table


def board_rights(board: str, rovers: Sequence[str]) -> dict[str, Rights]:
    """Who may do what on a board's own broker: its edge (the board's publisher, dashboard, tools), its rovers."""
    table = {
        EDGE_USER: Rights(publish=(board_topics(board), FORMATION_TOPIC), read=(ALL_TOPICS,)),
    }
    table.update({rover: rover_rights(rover) for rover in rovers})
    table[VIEWER_USER] = VIEWER_RIGHTS
    return table


@dataclass(frozen=True)
class BridgeFiles:
    central: Path
    boards: dict[str, Path]

    def all(self) -> list[Path]:
        out = sorted(self.central.iterdir())
        for where in self.boards.values():
            out += sorted(where.iterdir())
        return out


def _limits() -> list[str]:
    return [
        "per_listener_settings false",
        "allow_anonymous false",
        "# Several boards' messages: detections (up to 64 rovers) and the fusers' statuses are the largest.",
        f"max_packet_size {PACKET_LIMIT_BYTES}",
        f"message_size_limit {MESSAGE_LIMIT_BYTES}",
        "set_tcp_nodelay true",
    ]


def _central_conf(where: Path, port: int, local_port: int, tls_port: int | None, boards: Sequence[str]) -> str:
    lines = [
        f"# Central Mosquitto of several edge-ips boards ({', '.join(boards)}), written by",
        "# `edge-ips broker-config --bridge`. The fusers (edge-ips fuse) and the rovers connect here.",
        *_limits(),
        f"password_file {where / 'passwd'}",
        f"acl_file {where / 'acl'}",
        "",
        "# The operators' tools on this machine (edge-ips formation, doctor) with the edge login.",
        f"listener {local_port} 127.0.0.1",
        "",
        "# Rovers, the boards' bridges and the fusers: a client's id is its user name.",
        f"listener {port} 0.0.0.0",
        "use_username_as_clientid true",
        "",
    ]
    if tls_port is not None:
        lines += [
            "# The boards' bridges leave their boards over TLS: only clients with client.crt connect.",
            f"listener {tls_port} 0.0.0.0",
            "use_username_as_clientid true",
            f"cafile {where / 'ca.crt'}",
            f"certfile {where / 'server.crt'}",
            f"keyfile {where / 'server.key'}",
            "require_certificate true",
            "tls_version tlsv1.2",
            "",
        ]
    return "\n".join(lines)


def _board_conf(
    board: str,
    where: Path,
    *,
    central_host: str,
    central_port: int,
    password: str,
    local_port: int,
    port: int,
    tls: bool,
) -> str:
    lines = [
        f"# Mosquitto of board {board!r}, bridged to the central broker {central_host}:{central_port}; written by",
        "# `edge-ips broker-config --bridge`. edge-ips on this board: broker.url = mqtt://edge@localhost:"
        f'{local_port}, edge.publish = "detections".',
        *_limits(),
        f"password_file {where / 'passwd'}",
        f"acl_file {where / 'acl'}",
        "",
        f"listener {local_port} 127.0.0.1",
        "",
        f"listener {port} 0.0.0.0",
        "use_username_as_clientid true",
        "",
        "connection central",
        f"address {central_host}:{central_port}",
        f"remote_username {board}",
        f"remote_password {password}",
        f"remote_clientid {board}",
        "cleansession true",
        "keepalive_interval 5",
        "restart_timeout 1 10",
        "notifications true",
        "notifications_local_only false",
        f"notification_topic {bridge_state_topic(board)}",
        f"topic {board_topics(board)} out 1",
        f"topic {rover_status_topic('+')} out 1",
        f"topic {POSE_WILDCARD} in 0",
        f"topic {FUSER_STATUS_WILDCARD} in 1",
        f"topic {FORMATION_TOPIC} both 1",
    ]
    if tls:
        lines += [
            f"bridge_cafile {where / 'ca.crt'}",
            f"bridge_certfile {where / 'client.crt'}",
            f"bridge_keyfile {where / 'client.key'}",
            "bridge_tls_version tlsv1.2",
        ]
    return "\n".join(lines) + "\n"


def _credentials(title: str, logins: Mapping[str, Mapping[str, str]]) -> str:
    lines = [
        f"# {title}",
        "# Clear-text logins written by `edge-ips broker-config --bridge`. Keep secret (mode 600).",
        "",
    ]
    for table, users in logins.items():
        for user, password in users.items():
            lines += [f"[{table}.{user}]", f"username = {json.dumps(user)}", f"password = {json.dumps(password)}", ""]
    return "\n".join(lines)


def write_bridge_configs(
    out_dir: Path,
    *,
    boards: Sequence[str],
    rovers: Sequence[str],
    central_host: str,
    fusers: Sequence[str] = ("fuser-a", "fuser-b"),
    port: int = CENTRAL_PORT,
    local_port: int = LOCAL_PORT,
    tls_port: int | None = None,
    tls_names: Sequence[str] = (),
    install_dir: Path | None = None,
    force: bool = False,
) -> BridgeFiles:
    """``out_dir/central`` (the central broker) and ``out_dir/<board>`` for each board, with random passwords.

    ``central_host``: how the boards reach the central broker; ``install_dir``: where each directory will live on
    its machine (``<install_dir>/central``, ``<install_dir>/<board>``; default: ``out_dir``'s)."""
    if len(boards) < 1:
        raise BrokerError("--bridge needs the boards' ids (--boards cam1,cam2)")
    check_names(EDGE_USER, [*boards, *fusers, *rovers])
    if not all(f.startswith("fuser") for f in fusers):
        raise BrokerError("fuser logins start with 'fuser' (fuser-a, fuser-b)")
    dirs = {"central": out_dir / "central", **{b: out_dir / b for b in boards}}
    existing = [str(d) for d in dirs.values() if d.exists() and any(d.iterdir())]
    if existing and not force:
        raise BrokerError(f"{', '.join(existing)} already exist (use --force to overwrite)")
    base = install_dir if install_dir is not None else out_dir.resolve()
    for d in dirs.values():
        private_dir(d)
    passwords = {user: new_password() for user in [EDGE_USER, *boards, *fusers, *rovers, VIEWER_USER]}
    central = dirs["central"]
    tls = tls_port is not None
    if tls:
        write_tls_files(central, list(tls_names) or [central_host])
    write_password_file(central / "passwd", passwords)
    write_private(central / "acl", rights_acl_text(central_rights(boards, fusers, rovers)), mode=0o640)
    write_private(
        central / "mosquitto.conf", _central_conf(base / "central", port, local_port, tls_port, boards), mode=0o644
    )
    write_private(
        central / "credentials.toml",
        _credentials(
            "Central broker logins: [edge] for the operators' tools, [bridges.*] for the boards' bridges, [fusers.*]"
            " for edge-ips fuse, [rovers.*] for the firmware, [viewer.*] read-only.",
            {
                "edge": {EDGE_USER: passwords[EDGE_USER]},
                "bridges": {b: passwords[b] for b in boards},
                "fusers": {f: passwords[f] for f in fusers},
                "rovers": {r: passwords[r] for r in rovers},
                "viewer": {VIEWER_USER: passwords[VIEWER_USER]},
            },
        ),
    )
    board_dirs = {}
    for board in boards:
        where = dirs[board]
        local = {EDGE_USER: new_password(), **{r: passwords[r] for r in rovers}, VIEWER_USER: passwords[VIEWER_USER]}
        write_password_file(where / "passwd", local)
        write_private(where / "acl", rights_acl_text(board_rights(board, rovers)), mode=0o640)
        write_private(
            where / "mosquitto.conf",
            _board_conf(
                board,
                base / board,
                central_host=central_host,
                central_port=tls_port if tls_port is not None else port,
                password=passwords[board],
                local_port=local_port,
                port=port,
                tls=tls,
            ),
            mode=0o600,  # it holds the bridge's password
        )
        if tls:
            for name in ("ca.crt", "client.crt", "client.key"):
                shutil.copyfile(central / name, where / name)
                (where / name).chmod(0o600 if name.endswith(".key") else 0o644)
        write_private(
            where / "credentials.toml",
            _credentials(
                f"Board {board}'s broker: [edge] for edge-ips on the board, [rovers.*] for rovers that connect here.",
                {"edge": {EDGE_USER: local[EDGE_USER]}, "rovers": {r: local[r] for r in rovers}},
            ),
        )
        board_dirs[board] = where
    return BridgeFiles(central, board_dirs)
