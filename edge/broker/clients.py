"""The appliance's side of its broker: which broker the edge's own clients (publisher, dashboard,
``edge-ips formation``, ``doctor``, the closed loop) talk to, and starting the embedded one with the state
directory's logins."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from edge.broker.credentials import credentials_path, ensure_credentials, read_credentials
from edge.broker.embedded import EmbeddedBroker
from edge.broker.gate import BrokerAccess
from edge.config import BrokerSection, BrokerTarget, EdgeConfig, broker_target, parse_broker_url, state_dir
from edge.errors import BrokerError, ConfigError


@dataclass
class SelectedBroker:
    """The broker the edge's clients connect to (``target``), and the embedded broker started for it (``started``,
    None when none was: its owner stops it with :meth:`stop`)."""

    target: BrokerTarget
    started: EmbeddedBroker | None = None

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the embedded broker started for this (idempotent); a broker elsewhere is not ours to stop."""
        if self.started is not None:
            self.started.stop(timeout_s=timeout_s)
            self.started = None


def select_broker(config: EdgeConfig, *, start: bool = False, closed: bool = True) -> SelectedBroker:
    """The one rule for which broker the edge talks to (``start``, ``doctor``, ``formation``, the closed loop).

    ``broker.url`` a URL: that broker, with the section's login where the URL has none; nothing is started.
    ``embedded`` with ``start``: the embedded broker, started here. ``closed`` (the appliance): with the state
    directory's logins (made on the first start, a login added for a rover configured since), the target carrying
    the edge's login; not ``closed`` (a simulation): no logins, clients from this machine only, the target a plain
    one to its port. ``embedded`` without ``start``: the running appliance's, with the edge's login from the state
    directory (:class:`BrokerError` when there is none: the appliance has not started yet, or the login file
    belongs to another user).
    """
    target = broker_target(config.broker)
    if not target.embedded:
        return SelectedBroker(target)
    if not start:
        return SelectedBroker(_with_edge_login(config, target))
    if closed:
        return _start_closed(config, target)
    broker = EmbeddedBroker(target.host, target.port).start()
    return SelectedBroker(BrokerTarget(embedded=False, host=target.host, port=broker.port), broker)


def simulation_broker(url: str | None, option: str = "--broker") -> SelectedBroker:
    """A simulation's broker: ``url`` (``mqtt://host:port``), or with None or ``embedded`` an open embedded one
    started on a free port of 127.0.0.1. A bad URL is a :class:`ConfigError` naming ``option``."""
    if url is not None:
        try:
            parse_broker_url(url)
        except ValueError as exc:
            raise ConfigError(f"{option}: {exc}") from None
    section = BrokerSection(url=url or "embedded", embedded_host="127.0.0.1", embedded_port=0)
    return select_broker(EdgeConfig(broker=section), start=True, closed=False)


def embedded_credentials(config: EdgeConfig) -> Path:
    """Where the embedded broker's logins are (or will be, after the first start)."""
    return credentials_path(state_dir(config))


def _start_closed(config: EdgeConfig, target: BrokerTarget) -> SelectedBroker:
    directory = state_dir(config)
    credentials = ensure_credentials(directory, [r.id for r in config.rovers])
    access = BrokerAccess.of(credentials, config.edge.id, credentials_path(directory))
    broker = EmbeddedBroker(target.host, target.port, access).start()
    login = credentials.edge
    return SelectedBroker(replace(target, port=broker.port, username=login.username, password=login.password), broker)


def _with_edge_login(config: EdgeConfig, target: BrokerTarget) -> BrokerTarget:
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
