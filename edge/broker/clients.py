"""The appliance's side of its broker: starting the embedded one with the state directory's logins, and the
target the edge's own clients (publisher, dashboard, ``edge-ips formation``, ``doctor``) connect to."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from edge.broker.credentials import credentials_path, ensure_credentials, read_credentials
from edge.broker.embedded import EmbeddedBroker
from edge.broker.gate import BrokerAccess
from edge.config import BrokerTarget, EdgeConfig, broker_target, state_dir
from edge.errors import BrokerError


def embedded_credentials(config: EdgeConfig) -> Path:
    """Where the embedded broker's logins are (or will be, after the first start)."""
    return credentials_path(state_dir(config))


def start_embedded(config: EdgeConfig) -> tuple[EmbeddedBroker, BrokerTarget]:
    """Start the embedded broker with the state directory's logins (made on the first start, a login added for a
    rover configured since); returns it and the target for the edge's clients, with the edge's login."""
    target = broker_target(config.broker)
    directory = state_dir(config)
    credentials = ensure_credentials(directory, [r.id for r in config.rovers])
    access = BrokerAccess.of(credentials, config.edge.id, credentials_path(directory))
    broker = EmbeddedBroker(target.host, target.port, access).start()
    login = credentials.edge
    return broker, replace(target, port=broker.port, username=login.username, password=login.password)


def edge_target(config: EdgeConfig) -> BrokerTarget:
    """The broker the edge's command-line clients use: the configured one, or the embedded broker with the edge's
    login from the state directory (an error when there is none: the appliance has not started yet, or the
    login file belongs to another user)."""
    target = broker_target(config.broker)
    if not target.embedded:
        return target
    path = embedded_credentials(config)
    if not path.exists():
        raise BrokerError(
            f"{path}: no embedded broker logins yet. Start the appliance first (edge-ips start), or point "
            "edge.state_dir at the directory it uses"
        )
    login = read_credentials(path).edge
    return replace(target, username=login.username, password=login.password)


def broker_summary(config: EdgeConfig) -> str:
    """What the broker is doing, for the first log line: address, logins, where the logins are."""
    target = broker_target(config.broker)
    if target.embedded:
        return (
            f"embedded (amqtt on {target.host}:{target.port}; logins required, in {embedded_credentials(config)}; "
            "anonymous: read-only, from this machine only)"
        )
    login = f"login {target.username}" if target.username else "anonymous"
    return f"{target.display()} ({'TLS' if target.tls else 'no TLS'}, {login})"
