"""The files of a Mosquitto deployment (``edge-ips broker-config``): configuration, password file, ACL, logins.

Listeners, and why there are two (four with TLS):

* ``127.0.0.1:<local port>`` (1884): the edge's own clients on the broker's machine. The publisher, the dashboard,
  ``edge-ips formation`` and ``doctor`` share the edge's login and need their own client ids, so this listener
  keeps the ids clients choose; only processes on this machine reach it, and only with the edge's login
  (``passwd-local``): a rover's login, read out of its flash, would otherwise take the edge's session here.
* ``<bind>:<port>`` (1883): rovers and the rest of the network, with ``use_username_as_clientid true``: a client's id
  is its user name, so a login (a rover's, read out of its flash) cannot take the session of another user's client.
* ``--tls``: ``<bind>:<tls port>`` (8883) for the edge on other machines; only clients holding the client
  certificate connect (``require_certificate``), and only with the edge's login (``passwd-tls``): its clients share
  that login, so this listener too keeps the ids clients choose. And ``<bind>:<tls port + 1>`` (8884) for the
  viewer's login (``passwd-tls-viewer``: laptops watching the topics), with the certificate too and
  ``use_username_as_clientid true``: with the viewer's password and the certificate one can read, not take an edge
  client's session (which on 8883 it could). Rovers never use TLS.

Each listener has its own password file (``per_listener_settings true``). The network listeners keep at most
:data:`NETWORK_MAX_CONNECTIONS` (1883) and :data:`TLS_MAX_CONNECTIONS` (each TLS one) sockets: Mosquitto never
closes a socket that sends no CONNECT, and under systemd it has 1024 file descriptors, so a host on the network
opening a thousand silent sockets took them all, and the edge's own clients (its reconnection, the dashboard's STOP,
``edge-ips formation``: each a new connection to the loopback listener) were refused; with the caps they keep
room. Anonymous access is off everywhere;
the ACL is :meth:`edge.broker.access.Policy.acl_text`. Packets larger than
:data:`~edge.broker.access.MAX_PACKET_BYTES` disconnect their sender, payloads larger than the contract's largest
``x-max-bytes`` are dropped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from edge.broker.access import MAX_PACKET_BYTES, MAX_PAYLOAD_BYTES, hashed_users
from edge.broker.credentials import Credentials, generate
from edge.broker.tls import TLS_FILES, TlsPaths, tls_listener_lines, write_tls_files
from edge.errors import BrokerError
from edge.private_files import private_dir, write_private

LOCAL_PORT = 1884
TLS_PORT = 8883
NETWORK_MAX_CONNECTIONS = 512  # rovers, viewers, laptops on 1883: far more than a fleet (64 rovers at most)
TLS_MAX_CONNECTIONS = 64  # on each TLS listener
LOCAL_PASSWD = "passwd-local"  # the local listener's logins: the edge's only
TLS_PASSWD = "passwd-tls"  # the edge's TLS listener's: the edge's only
TLS_VIEWER_PASSWD = "passwd-tls-viewer"  # the viewer's TLS listener's (tls port + 1): the viewer's only


def write_password_file(path: Path, passwords: Mapping[str, str]) -> Path:
    """``user:$7$...`` lines (:func:`~edge.broker.access.mosquitto_hash`), mode 0600 from the first byte."""
    hashes = hashed_users(passwords)
    return write_private(path, "".join(f"{user}:{hashed}\n" for user, hashed in hashes.items()))


@dataclass(frozen=True)
class BrokerFiles:
    conf: Path
    passwd: Path
    acl: Path
    credentials: Path
    local_passwd: Path
    tls_passwd: Path | None = None
    tls: TlsPaths | None = None
    tls_viewer_passwd: Path | None = None

    def all(self) -> list[Path]:
        tls = [] if self.tls is None else [self.tls_passwd, self.tls_viewer_passwd, *vars(self.tls).values()]
        return [self.conf, self.passwd, self.local_passwd, self.acl, self.credentials, *[p for p in tls if p]]


def login_lines(where: Path, passwd: str) -> list[str]:
    """A listener's own security settings (``per_listener_settings true``): logins from ``where/passwd``, one ACL."""
    return ["allow_anonymous false", f"password_file {where / passwd}", f"acl_file {where / 'acl'}"]


def _conf_text(
    *,
    credentials: Credentials,
    edge_id: str,
    where: Path,
    port: int,
    bind: str,
    local_port: int,
    tls_port: int | None,
) -> str:
    rovers = ", ".join(credentials.rovers) or "none"
    lines = [
        f"# Mosquitto configuration for edge-ips (edge {edge_id!r}; rovers {rovers}),",
        f"# written by `edge-ips broker-config`. Install: copy this directory to {where} and include this file",
        "# from /etc/mosquitto/conf.d/. Who may do what: docs/deploy.md, section 'Security model'.",
        "# Each listener names the logins it takes (a rover's is no key to the edge's listeners); one ACL.",
        "per_listener_settings true",
        "# Nothing edge-ips sends is larger: a bigger packet disconnects its sender, a bigger payload is dropped.",
        f"max_packet_size {MAX_PACKET_BYTES}",
        f"message_size_limit {MAX_PAYLOAD_BYTES}",
        "# Forward each small pose at once (Nagle's algorithm would hold it for the rover's delayed ACK):",
        "set_tcp_nodelay true",
        "# Keep the system's `persistence true` (Debian's default): the retained formation survives restarts.",
        "",
        "# The edge's own clients on this machine (publisher, dashboard, `edge-ips formation`, doctor): they share",
        "# the edge's login, so they keep their own client ids. Only processes on this machine reach it, and only",
        "# with the edge's login: with a rover's (read out of its flash) one could take the edge's session here.",
        f"listener {local_port} 127.0.0.1",
        *login_lines(where, LOCAL_PASSWD),
        "",
        "# Rovers and the rest of the network. A client's id is its user name here, so no login can take the",
        "# session of another user's client (a rover's password cannot disconnect the edge). At most so many",
        "# sockets: silent ones from the network must leave file descriptors for the edge's listener.",
        f"listener {port} {bind}",
        f"max_connections {NETWORK_MAX_CONNECTIONS}",
        "use_username_as_clientid true",
        *login_lines(where, "passwd"),
        "",
    ]
    if tls_port is not None:
        lines += [
            "# TLS for the edge on other machines: only clients with client.crt (signed by ca.crt) connect, with",
            "# the edge's login; its clients share it, so they keep their ids. ESP8266 rovers stay on the plain",
            "# listener (docs/deploy.md).",
            *[line for line in tls_listener_lines(tls_port, bind, where, max_connections=TLS_MAX_CONNECTIONS) if line],
            *login_lines(where, TLS_PASSWD),
            "",
        ]
    if tls_port is not None and credentials.viewer is not None:
        lines += [
            "# TLS for laptops watching the topics: the certificate and the viewer's login; a client's id is its",
            "# user name here, so the viewer's password cannot take an edge client's session.",
            *[
                line
                for line in tls_listener_lines(
                    tls_port + 1, bind, where, clientid_from_username=True, max_connections=TLS_MAX_CONNECTIONS
                )
                if line
            ],
            *login_lines(where, TLS_VIEWER_PASSWD),
            "",
        ]
    return "\n".join(lines)


CREDENTIALS_HEADER = (
    "Clear-text logins written by `edge-ips broker-config`. Keep this file secret (mode 600).",
    "The edge: [broker] username/password in edge-ips.toml (or EDGE_IPS_BROKER__PASSWORD).",
    "Each rover: the firmware's MQTT user and password (edge-ips flash provisions them).",
    "[viewer]: reads every ips/v1 topic, publishes nothing.",
)


def write_mosquitto_config(
    out_dir: Path,
    *,
    rovers: Sequence[str],
    edge_id: str = "edge-1",
    edge_user: str = "edge",
    port: int = 1883,
    bind: str = "0.0.0.0",
    local_port: int = LOCAL_PORT,
    tls_port: int | None = None,
    tls_names: Sequence[str] = (),
    install_dir: Path | None = None,
    passwords: Mapping[str, str] | None = None,
    viewer: bool = True,
    force: bool = False,
) -> BrokerFiles:
    """Write ``mosquitto.conf``, ``passwd``, ``acl`` and ``credentials.toml`` (and the TLS files with ``tls_port``).

    ``install_dir`` is where the conf will find the other files on the broker machine (default: ``out_dir``).
    Passwords are random unless given in ``passwords`` (user -> password).
    """
    credentials = generate(rovers, edge_user=edge_user, viewer=viewer, passwords=passwords)
    tls_ports = [] if tls_port is None else [tls_port] + ([tls_port + 1] if viewer else [])
    if len({port, local_port, *tls_ports}) != 2 + len(tls_ports) or any(p > 65535 for p in tls_ports):
        listed = ", ".join(str(p) for p in (port, local_port, *tls_ports))
        raise BrokerError(f"listener ports must differ (the viewer's TLS listener is the TLS port + 1): {listed}")
    tls_names_written: list[str] = [] if tls_port is None else [TLS_PASSWD, *TLS_FILES]
    tls_names_written += [TLS_VIEWER_PASSWD] if tls_port is not None and viewer else []
    names = ["mosquitto.conf", "passwd", LOCAL_PASSWD, "acl", "credentials.toml", *tls_names_written]
    existing = [name for name in names if (out_dir / name).exists()]
    if existing and not force:
        raise BrokerError(f"{out_dir}: {', '.join(existing)} already exist (use --force to overwrite)")
    private_dir(out_dir)
    where = install_dir if install_dir is not None else out_dir.resolve()
    tls = write_tls_files(out_dir, tls_names) if tls_port is not None else None
    passwords = credentials.passwords()
    passwd = write_password_file(out_dir / "passwd", passwords)
    edge_only = {credentials.edge.username: passwords[credentials.edge.username]}
    local_passwd = write_password_file(out_dir / LOCAL_PASSWD, edge_only)
    tls_passwd = tls_viewer_passwd = None
    if tls_port is not None:
        tls_passwd = write_password_file(out_dir / TLS_PASSWD, edge_only)
        if credentials.viewer is not None:
            viewer_only = {credentials.viewer.username: credentials.viewer.password}
            tls_viewer_passwd = write_password_file(out_dir / TLS_VIEWER_PASSWD, viewer_only)
    acl = write_private(out_dir / "acl", credentials.policy(edge_id).acl_text(), mode=0o640)
    conf = write_private(
        out_dir / "mosquitto.conf",
        _conf_text(
            credentials=credentials,
            edge_id=edge_id,
            where=where,
            port=port,
            bind=bind,
            local_port=local_port,
            tls_port=tls_port,
        ),
        mode=0o644,
    )
    secrets = write_private(out_dir / "credentials.toml", credentials.to_toml(CREDENTIALS_HEADER))
    return BrokerFiles(conf, passwd, acl, secrets, local_passwd, tls_passwd, tls, tls_viewer_passwd)
