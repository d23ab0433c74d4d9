"""MQTT brokers for the appliance: the embedded amqtt broker, and configuration files for a Mosquitto deployment.

The embedded broker lets rovers connect to the camera board with nothing else installed: amqtt (MQTT 3.1.1) on
its own thread with its own asyncio event loop, anonymous, retained messages and last wills included. For a
deployment with users and ACLs, :func:`write_mosquitto_config` writes what Mosquitto needs (``edge-ips
broker-config``): anonymous access off, the edge may publish poses, its status and the formation, each rover may
read poses and the formation and publish only its own status.
"""

from __future__ import annotations

import asyncio
import base64
import errno
import hashlib
import logging
import os
import re
import secrets
import shutil
import subprocess
import threading
from collections.abc import Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edge.errors import BrokerError
from edge.messages import (
    FORMATION_TOPIC,
    ID_PATTERN,
    POSE_WILDCARD,
    ROVER_STATUS_WILDCARD,
    TOPIC_PREFIX,
    edge_status_topic,
)
from edge.messages import rover_status_topic as _rover_status_topic

log = logging.getLogger("edge.broker")


def _amqtt_noise(record: logging.LogRecord) -> bool:
    """False for what amqtt logs that this module says better: its traceback when it cannot listen (start() raises
    a one-line BrokerError instead), and its warning of the QoS 0 messages still queued when it stops (dropping them
    on shutdown is the design)."""
    text = record.getMessage()
    return text != "Broker startup failed" and "messages not broadcasted" not in text


# -- the embedded broker -----------------------------------------------------------------------------------------
def _make_broker(config: dict[str, Any]) -> Any:
    """An amqtt broker that sends a connecting client only the retained messages of its own subscriptions.

    amqtt 0.12.1 (``Broker._handle_client_session``) pushes, to every client that connects, the retained messages
    matching *any* client's subscriptions: a rover would receive topics it never subscribed to. The override
    skips subscriptions the session does not hold (pinned: amqtt >=0.12,<0.13; a test pins the behaviour).
    """
    from amqtt.broker import Broker

    class _Broker(Broker):
        async def _publish_retained_messages_for_subscription(
            self, subscription: tuple[str, int], session: Any
        ) -> None:
            holders = self._subscriptions.get(subscription[0], [])
            if any(s.client_id == session.client_id for s, _ in holders):
                await super()._publish_retained_messages_for_subscription(subscription, session)

    return _Broker(config, loop=asyncio.get_running_loop())


class EmbeddedBroker:
    """An amqtt broker on ``host:port`` (port 0 = any free port; see :attr:`port` after :meth:`start`)."""

    def __init__(self, host: str = "0.0.0.0", port: int = 1883) -> None:
        self.host, self._port = host, port
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._broker: Any = None
        self._started: Future[int] = Future()

    @property
    def port(self) -> int:
        return self._port

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _port_in_use_message(self) -> str:
        return (
            f"embedded broker: port {self._port} on {self.host} is already in use (another MQTT broker, such as a "
            "Mosquitto service?). Choose another with broker.embedded_port in the configuration or "
            "EDGE_IPS_BROKER__EMBEDDED_PORT, or publish to the running broker with --broker mqtt://localhost:"
            f"{self._port}"
        )

    async def _serve(self) -> None:
        config = {
            "listeners": {"default": {"type": "tcp", "bind": f"{self.host}:{self._port}"}},
            # Only anonymous authentication: amqtt's default plugin set adds $SYS topics and packet logging.
            "plugins": {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}},
        }
        broker = _make_broker(config)
        try:
            await broker.start()
        except Exception as exc:
            self._started.set_exception(exc)
            return
        self._broker = broker
        server = broker._servers["default"].instance  # the bound port when 0 was asked for
        port = int(server.sockets[0].getsockname()[1])
        self._started.set_result(port)
        self._stop_requested = asyncio.Event()
        await self._stop_requested.wait()
        await broker.shutdown()

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        finally:
            loop.close()

    def start(self, timeout_s: float = 10.0) -> EmbeddedBroker:
        """Start listening; raises :class:`BrokerError` (port taken, bad address) before returning."""
        if self.running:
            raise BrokerError(f"embedded broker on {self.host}:{self._port} is already running")
        for name in ("amqtt", "transitions"):
            if logging.getLogger(name).level == logging.NOTSET:
                logging.getLogger(name).setLevel(logging.WARNING)  # amqtt logs every connection at INFO
        if _amqtt_noise not in logging.getLogger("amqtt.broker").filters:
            logging.getLogger("amqtt.broker").addFilter(_amqtt_noise)
        self._thread = threading.Thread(target=self._run, name="embedded-broker", daemon=True)
        self._thread.start()
        try:
            self._port = self._started.result(timeout=timeout_s)
        except TimeoutError:
            raise BrokerError(f"embedded broker did not start within {timeout_s:g} s") from None
        except Exception as exc:
            self._thread.join(timeout=5)
            cause: BaseException | None = exc
            while cause is not None:
                if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
                    raise BrokerError(self._port_in_use_message()) from exc
                if isinstance(cause, OSError) and cause.errno == errno.EACCES:
                    raise BrokerError(
                        f"embedded broker: no permission to listen on port {self._port} (below 1024 needs root)"
                    ) from exc
                cause = cause.__cause__ or cause.__context__
            raise BrokerError(f"embedded broker on {self.host}:{self._port} cannot start: {exc}") from exc
        log.info("embedded MQTT broker (amqtt) listening on %s:%d", self.host, self._port)
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        event = getattr(self, "_stop_requested", None)
        if event is not None:
            loop.call_soon_threadsafe(event.set)
        thread.join(timeout=timeout_s)
        self._thread = None
        log.info("embedded MQTT broker stopped")

    def __enter__(self) -> EmbeddedBroker:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


# -- Mosquitto deployment files ----------------------------------------------------------------------------------
PBKDF2_ITERATIONS = 101  # what mosquitto_passwd 2.0 writes
PBKDF2_SALT_BYTES = 12


def mosquitto_hash(password: str, salt: bytes | None = None) -> str:
    """A Mosquitto 2.0 password hash, ``$7$<iterations>$<base64 salt>$<base64 PBKDF2-SHA512>``.

    Used only when ``mosquitto_passwd`` is not installed; a test checks a real Mosquitto accepts it.
    """
    salt = salt if salt is not None else os.urandom(PBKDF2_SALT_BYTES)
    digest = hashlib.pbkdf2_hmac("sha512", password.encode("utf-8"), salt, PBKDF2_ITERATIONS)
    return f"$7${PBKDF2_ITERATIONS}${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def write_password_file(path: Path, users: Mapping[str, str], *, use_tool: bool = True) -> str:
    """Write ``user:hash`` lines; hashes by ``mosquitto_passwd`` when available. Returns the method used."""
    tool = shutil.which("mosquitto_passwd") if use_tool else None
    path.write_text("")
    path.chmod(0o600)
    if tool is not None:
        for name, password in users.items():
            result = subprocess.run([tool, "-b", str(path), name, password], capture_output=True, text=True)
            if result.returncode != 0:
                raise BrokerError(f"mosquitto_passwd failed for user {name!r}: {result.stderr.strip()}")
        return "mosquitto_passwd"
    path.write_text("".join(f"{name}:{mosquitto_hash(password)}\n" for name, password in users.items()))
    return "pbkdf2-sha512"


def acl_text(edge_user: str, edge_id: str, rovers: Sequence[str]) -> str:
    """The ACL: the edge publishes poses, its status and the formation; a rover reads, and writes its own status."""
    lines = [
        "# edge-ips ACL, written by `edge-ips broker-config`.",
        "# Anonymous access is off; a user not listed here can do nothing.",
        "",
        f"user {edge_user}",
        f"topic write {POSE_WILDCARD}",
        f"topic readwrite {edge_status_topic(edge_id)}",
        f"topic readwrite {FORMATION_TOPIC}",
        f"topic read {ROVER_STATUS_WILDCARD}",
        "",
    ]
    for rover in rovers:
        lines += [
            f"user {rover}",
            f"topic read {POSE_WILDCARD}",
            f"topic read {FORMATION_TOPIC}",
            f"topic read {TOPIC_PREFIX}/edge/+/status",
            f"topic write {_rover_status_topic(rover)}",
            "",
        ]
    return "\n".join(lines)


@dataclass(frozen=True)
class BrokerFiles:
    conf: Path
    passwd: Path
    acl: Path
    credentials: Path
    hash_method: str


def write_mosquitto_config(
    out_dir: Path,
    *,
    rovers: Sequence[str],
    edge_id: str = "edge-1",
    edge_user: str = "edge",
    port: int = 1883,
    bind: str = "0.0.0.0",
    install_dir: Path | None = None,
    passwords: Mapping[str, str] | None = None,
    use_tool: bool = True,
    force: bool = False,
) -> BrokerFiles:
    """Write ``mosquitto.conf``, ``passwd``, ``acl`` and ``credentials.toml`` (the clear passwords) to ``out_dir``.

    ``install_dir`` is where the conf will find passwd and acl on the broker machine (default: ``out_dir``).
    Passwords are random unless given in ``passwords`` (user -> password).
    """
    for name in [edge_user, *rovers]:
        if not re.match(ID_PATTERN, name):
            raise BrokerError(f"user name {name!r}: use 1-16 characters of a-z, 0-9, _ and -")
    if edge_user in rovers:
        raise BrokerError(f"the edge user {edge_user!r} must differ from every rover id")
    if len(set(rovers)) != len(rovers):
        raise BrokerError("rover ids must be unique")
    out_dir.mkdir(parents=True, exist_ok=True)
    files = [out_dir / n for n in ("mosquitto.conf", "passwd", "acl", "credentials.toml")]
    existing = [p.name for p in files if p.exists()]
    if existing and not force:
        raise BrokerError(f"{out_dir}: {', '.join(existing)} already exist (use --force to overwrite)")
    conf, passwd, acl, credentials = files
    where = install_dir if install_dir is not None else out_dir.resolve()
    users = {u: (passwords or {}).get(u) or secrets.token_urlsafe(18) for u in [edge_user, *rovers]}

    method = write_password_file(passwd, users, use_tool=use_tool)
    acl.write_text(acl_text(edge_user, edge_id, rovers))
    acl.chmod(0o640)
    conf.write_text(
        "\n".join(
            [
                f"# Mosquitto configuration for edge-ips (edge {edge_id!r}; rovers {', '.join(rovers)}),",
                "# written by `edge-ips broker-config`. Install: copy this directory to "
                f"{where} and include this file from /etc/mosquitto/conf.d/.",
                "per_listener_settings false",
                f"listener {port} {bind}",
                "allow_anonymous false",
                "# Forward each small pose at once (Nagle's algorithm would hold it for the rover's delayed ACK):",
                "set_tcp_nodelay true",
                f"password_file {where / 'passwd'}",
                f"acl_file {where / 'acl'}",
                "# Keep the system's `persistence true` (Debian's default): the retained formation survives restarts.",
                "",
            ]
        )
    )
    lines = [
        "# Clear-text credentials written by `edge-ips broker-config`. Keep this file secret (mode 600).",
        "# The edge: [broker] username/password in edge-ips.toml (or EDGE_IPS_BROKER__PASSWORD).",
        "# Each rover: the firmware's MQTT user and password (tools/flash.py provisions them).",
        "",
        "[edge]",
        f'username = "{edge_user}"',
        f'password = "{users[edge_user]}"',
        "",
    ]
    for rover in rovers:
        lines += [f"[rovers.{rover}]", f'username = "{rover}"', f'password = "{users[rover]}"', ""]
    credentials.write_text("\n".join(lines))
    credentials.chmod(0o600)
    return BrokerFiles(conf, passwd, acl, credentials, method)
