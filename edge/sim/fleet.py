"""Simulated rovers on a real broker (``edge-ips sim rovers``): the real firmware of each rover on this computer.

Each rover is a :class:`~edge.rover_host.HostRover` (the flashed modules ``rover.py``, ``link.py``, ``msg.py``,
``formation.py``...; host stand-ins for motors, Wi-Fi and the clock) and so its own MQTT client, with its own client
id (``rover-<id>``) and credentials, as on the floor. A :class:`RoverRunner` steps one rover on a :class:`Clock`
at the firmware's period; its motor commands stay readable (:attr:`RoverRunner.wheel_speeds_cm_s`,
:attr:`RoverRunner.motor_state`), so a live twin can step the same runners on its own clock and move simulated
bodies by what the firmware drives. :class:`SimFleet` runs one runner per rover, each on its own thread (a rover
whose link blocks does not hold the others up), until it is closed.

Credentials come from a directory of per-rover configs (``DIR/<id>/config.json`` as ``edge-ips flash --bundle
DIR/<id>`` writes it, or ``DIR/<id>.json``) or from a credentials file (``[rovers.<id>] username, password``, as
``edge-ips broker-config`` writes it); without either, the example configs with user ``<id>`` and no password.
The broker's address comes from ``--broker`` (the bundles name the lab's broker as the rovers see it).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from edge.config import parse_broker_url
from edge.errors import ConfigError, EdgeIpsError, MessageError
from edge.messages import RoverStatusV2, id_problem, parse_rover_status
from edge.rover_host import CONFIG_DIR, HostRover, MotorState, check_rover_config

DEFAULT_IDS = ("red", "green", "blue")
TICKS_MASK = (1 << 30) - 1  # the ESP8266's time.ticks_ms() wraps at 2**30


class Clock(Protocol):
    """What a runner reads the time from and waits on: real time for ``sim rovers``, a simulation's for a twin."""

    def now_ms(self) -> int:
        """Milliseconds, wrapping at 2**30 like the ESP8266's ``time.ticks_ms()``."""
        ...

    def wait(self, seconds: float, stop: threading.Event) -> bool:
        """Wait ``seconds`` or until ``stop`` is set; True when stopped."""
        ...


class RealClock:
    def now_ms(self) -> int:
        return int(time.monotonic() * 1000) & TICKS_MASK

    def wait(self, seconds: float, stop: threading.Event) -> bool:
        return stop.wait(max(0.0, seconds))


class RoverRunner:
    """One rover's firmware loop: :meth:`step` once at the clock's time, or :meth:`run` at the firmware's period
    (``control.period_ms``) until stopped, as ``main.py`` does on the board."""

    def __init__(self, rover: HostRover, clock: Clock) -> None:
        self.rover = rover
        self.clock = clock
        self.period_ms = int(rover.config["control"]["period_ms"])

    @property
    def id(self) -> str:
        return self.rover.id

    def step(self) -> None:
        self.rover.step(self.clock.now_ms())

    def run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            t0 = self.clock.now_ms()
            self.step()
            spent = (self.clock.now_ms() - t0) & TICKS_MASK
            if self.clock.wait((self.period_ms - spent) / 1000, stop):
                break

    @property
    def wheel_speeds_cm_s(self) -> tuple[float, float]:
        """(left, right) rim speeds the motor duties stand for: what a twin moves its simulated body by."""
        return self.rover.wheel_speeds_cm_s

    @property
    def motor_state(self) -> MotorState:
        return self.rover.motor_state

    @property
    def halt(self) -> str:
        return self.rover.halt

    def close(self) -> None:
        """Motors off, the offline status, a clean disconnect (what Ctrl-C does on the board)."""
        self.rover.close()


# -- configuration -------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FleetBroker:
    host: str
    port: int


def rover_broker(url: str) -> FleetBroker:
    """The broker the simulated rovers connect to: ``mqtt://host[:port]`` (rovers speak plain MQTT, with their own
    credentials)."""
    try:
        target = parse_broker_url(url)
    except ValueError as exc:
        raise ConfigError(f"--broker: {exc}") from None
    if target.embedded:
        raise ConfigError(
            "--broker: give the broker's address, e.g. mqtt://localhost:1883 for an edge on this computer"
        )
    if target.tls:
        raise ConfigError(f"--broker {url}: rovers speak plain MQTT (the ESP8266 has no room for TLS): use mqtt://")
    if target.username is not None:
        raise ConfigError("--broker: no credentials in the URL: each rover uses its own (--config-dir, --credentials)")
    return FleetBroker(target.host, target.port)


def parse_ids(text: str) -> list[str]:
    ids = [i.strip() for i in text.split(",") if i.strip()]
    problem = "none given" if not ids else id_problem(ids)
    if problem is not None:
        raise ConfigError(f"--ids: {problem}")
    return ids


def ids_in(config_dir: Path) -> list[str]:
    """Rovers with a config in ``config_dir``: ``<id>/config.json`` (bundles) and ``<id>.json``, sorted."""
    found = {p.parent.name for p in config_dir.glob("*/config.json")} | {p.stem for p in config_dir.glob("*.json")}
    if not found:
        raise ConfigError(
            f"{config_dir}: no rover configs (<id>/config.json from `edge-ips flash --bundle`, or <id>.json)"
        )
    return sorted(found)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        given = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: {exc.strerror}") from None
    if not isinstance(given, dict):
        raise ConfigError(f"{path}: expected a JSON object")
    return given


def _rover_file(rover_id: str, config_dir: Path | None) -> Path:
    if config_dir is None:
        return CONFIG_DIR / f"{rover_id if rover_id in DEFAULT_IDS else DEFAULT_IDS[0]}.json"
    for path in (config_dir / rover_id / "config.json", config_dir / f"{rover_id}.json"):
        if path.is_file():
            return path
    raise ConfigError(f"{config_dir}: no config for rover {rover_id!r} ({rover_id}/config.json or {rover_id}.json)")


def read_credentials(path: Path) -> dict[str, tuple[str, str]]:
    """``{rover id: (user, password)}`` from a credentials file: ``broker-config``'s ``credentials.toml`` or the
    embedded broker's ``broker-credentials.toml`` in the state directory (one format, one reader)."""
    from edge.broker.credentials import read_credentials as read_logins

    return {rover: (login.username, login.password) for rover, login in read_logins(path).rovers.items()}


def fleet_configs(
    ids: Sequence[str], broker: FleetBroker, *, config_dir: Path | None = None, credentials: Path | None = None
) -> list[dict[str, Any]]:
    """Each rover's checked config: its file (see the module's docstring), its credentials, and ``broker``."""
    if config_dir is not None and not config_dir.is_dir():
        raise ConfigError(f"{config_dir}: no such directory")
    secrets = read_credentials(credentials) if credentials is not None else {}
    configs = []
    for rover_id in ids:
        path = _rover_file(rover_id, config_dir)
        given = _read_json(path)
        if config_dir is None:
            given = {**given, "id": rover_id, "broker": {**given.get("broker", {}), "user": rover_id}}
        elif given.get("id") != rover_id:
            raise ConfigError(f"{path}: its id is {given.get('id')!r}, not {rover_id!r}")
        if credentials is not None:
            if rover_id not in secrets:
                raise ConfigError(f"{credentials}: no [rovers.{rover_id}] credentials")
            user, password = secrets[rover_id]
            given = {**given, "broker": {**given.get("broker", {}), "user": user, "password": password}}
        given["broker"] = {**given.get("broker", {}), "host": broker.host, "port": broker.port}
        configs.append(check_rover_config(given, where=str(path)))
    return configs


# -- the fleet -----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FleetEvent:
    """Something a simulated rover did that its operator should see: a status it published, or its link."""

    rover_id: str
    text: str
    status: RoverStatusV2 | None = None


class SimFleet:
    """The firmware of each rover in ``configs`` on its own thread, connected to ``broker`` until :meth:`close`.

    ``on_event(FleetEvent)`` (called on the rovers' threads): each status a rover publishes that says something new
    (state, halt, formation or seq changed; not the 30 s refreshes), and each link change.
    """

    def __init__(
        self,
        configs: Sequence[Mapping[str, Any]],
        broker: FleetBroker,
        *,
        on_event: Callable[[FleetEvent], None] | None = None,
        clock: Clock | None = None,
    ) -> None:
        self.broker = broker
        self.on_event = on_event
        self.clock = clock or RealClock()
        self._said: dict[str, tuple[str, str, str | None, int | None]] = {}
        self.runners = [
            RoverRunner(
                HostRover(
                    cfg,
                    broker.host,
                    broker.port,
                    log=self._logger(cfg["id"]),
                    on_status=self._status_of(cfg["id"]),
                ),
                self.clock,
            )
            for cfg in configs
        ]
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def _emit(self, event: FleetEvent) -> None:
        if self.on_event is not None:
            self.on_event(event)

    def _logger(self, rover_id: str) -> Callable[..., None]:
        def log(*args: object) -> None:
            text = " ".join(str(a) for a in args)
            if text.startswith("broker"):  # the link: connected, or down and why
                self._emit(FleetEvent(rover_id, text))

        return log

    def _status_of(self, rover_id: str) -> Callable[[bytes], None]:
        def on_status(payload: bytes) -> None:
            try:
                status = parse_rover_status(payload)
            except MessageError as exc:  # the firmware broke the contract: say so, loudly
                self._emit(FleetEvent(rover_id, f"status breaks the contract: {exc}"))
                return
            key = (status.state, status.halt, status.formation, status.seq)
            if self._said.get(rover_id) == key:
                return
            self._said[rover_id] = key
            applies = "no formation" if status.formation is None else f"{status.formation} (seq {status.seq})"
            self._emit(FleetEvent(rover_id, f"{status.state}, halt {status.halt}, applies {applies}", status))

        return on_status

    def check(self) -> None:
        """Each rover connects once with its own credentials: :class:`BrokerError` for the first that cannot."""
        for runner in self.runners:
            runner.rover.check_broker()

    def start(self) -> SimFleet:
        for runner in self.runners:
            thread = threading.Thread(target=runner.run, args=(self._stop,), name=f"rover-{runner.id}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop every loop, then each rover says goodbye (offline status, clean disconnect)."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout_s)
        for runner in self.runners:
            runner.close()


def start_fleet(
    broker_url: str,
    ids: Sequence[str] | None = None,
    *,
    config_dir: Path | None = None,
    credentials: Path | None = None,
    on_event: Callable[[FleetEvent], None] | None = None,
) -> SimFleet:
    """Check everything (URL, configs, each rover's connection) and start the fleet; raises :class:`EdgeIpsError`
    subclasses with one-line messages."""
    broker = rover_broker(broker_url)
    if ids is None:
        ids = ids_in(config_dir) if config_dir is not None and config_dir.is_dir() else list(DEFAULT_IDS)
    configs = fleet_configs(ids, broker, config_dir=config_dir, credentials=credentials)
    fleet = SimFleet(configs, broker, on_event=on_event)
    try:
        fleet.check()
    except EdgeIpsError:
        fleet.close()
        raise
    return fleet.start()
