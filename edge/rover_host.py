"""The rover firmware, run on the host: one instance per simulated rover, stepped by a (simulated) clock.

The real modules of ``firmware/esp8266/`` run unchanged; only hardware is stood in for (``firmware/host/``:
``machine``, ``network``, MicroPython's ``time.ticks_*``, and a MicroPython-style socket under the vendored
``umqtt.simple``). They are imported by one module finder that knows exactly these files (``sys.path`` is left
alone), under the names the firmware imports them by (``import msg``), as on the board. Each :class:`HostRover`
owns its own motors, MQTT client and state, so a simulation can run a whole fleet in one process, faster than real
time: the firmware's clock is whatever ``now_ms`` the caller passes to :meth:`HostRover.step`.

Wheel commands come back as PWM duties (what the board would write) and as the wheel speeds those duties stand
for, through the invertible model of ``motors.py`` (:func:`duty_to_wheel_rad_s`).

Example::

    rover = HostRover(config, "127.0.0.1", 1883)
    for k in range(300):
        rover.step(k * 20)                     # 20 ms per step, as fast as the host can
        left, right = rover.wheel_speeds_cm_s  # feed these to the world simulator
"""

from __future__ import annotations

import copy
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from edge.errors import BrokerError, ConfigError

FIRMWARE_DIR = Path(__file__).resolve().parent.parent / "firmware" / "esp8266"
HOST_DIR = FIRMWARE_DIR.parent / "host"
CONFIG_DIR = FIRMWARE_DIR / "configs"

FIRMWARE_NAMES = ("msg", "formation", "config", "motors", "link", "rover", "app", "main")
HOST_NAMES = ("micropython", "machine", "network", "mptime", "mpsocket", "umqtt", "umqtt.simple")

_lock = threading.Lock()
_modules: dict[str, ModuleType] = {}


class FirmwareFinder(importlib.abc.MetaPathFinder):
    """Finds exactly the firmware's modules and the host stand-ins, by the names the firmware imports them by.

    Nothing else is served, so no other import in the process can land in ``firmware/``; and a module of one of
    these names found anywhere else (an installed ``machine`` package, say) cannot shadow them, since this finder is
    asked first.
    """

    def __init__(self, files: Mapping[str, Path]) -> None:
        self.files = dict(files)

    @classmethod
    def for_firmware(cls) -> FirmwareFinder:
        files = {name: FIRMWARE_DIR / f"{name}.py" for name in FIRMWARE_NAMES}
        for name in HOST_NAMES:
            parts = name.split(".")
            package = HOST_DIR.joinpath(*parts) / "__init__.py"
            files[name] = package if package.is_file() else HOST_DIR.joinpath(*parts[:-1], parts[-1] + ".py")
        return cls(files)

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        file = self.files.get(fullname)
        if file is None:
            return None
        package = [str(file.parent)] if file.name == "__init__.py" else None
        return importlib.util.spec_from_file_location(fullname, file, submodule_search_locations=package)


def firmware_modules() -> dict[str, ModuleType]:
    """Import the firmware's modules with the host stand-ins, through :class:`FirmwareFinder` (once per process).

    Returns ``{"msg": ..., "formation": ..., "config": ..., "motors": ..., "link": ..., "rover": ..., "main": ...}``.
    """
    with _lock:
        if _modules:
            return _modules
        finder = FirmwareFinder.for_firmware()
        if not any(isinstance(f, FirmwareFinder) for f in sys.meta_path):
            sys.meta_path.insert(0, finder)
        for name, file in finder.files.items():
            module = importlib.import_module(name)
            if Path(getattr(module, "__file__", "") or "").resolve() != file.resolve():
                raise ImportError(f"module {name} was already imported from {module.__file__}, not {file}")
            if name in FIRMWARE_NAMES:
                _modules[name] = module
        sys.modules["mptime"].install()
        simple: Any = sys.modules["umqtt.simple"]
        simple.socket = sys.modules["mpsocket"]  # MicroPython-style sockets (read/write) under the vendored client
        return _modules


def load_rover_config(name_or_path: str | Path) -> dict[str, Any]:
    """One of the example configs (``red``, ``green``, ``blue``) or a config.json path, merged with the firmware
    defaults and checked by the firmware's own ``config.check``; :class:`ConfigError` names the key at fault."""
    import json

    path = Path(name_or_path)
    if not path.suffix:
        path = CONFIG_DIR / f"{name_or_path}.json"
    try:
        given = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such rover config") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    return check_rover_config(given, where=str(path))


def check_rover_config(given: Mapping[str, Any], where: str = "rover config") -> dict[str, Any]:
    """Merge with the firmware defaults and check; :class:`ConfigError` names the key at fault."""
    config = firmware_modules()["config"]
    if not isinstance(given, Mapping):
        raise ConfigError(f"{where}: expected a JSON object")
    try:
        return dict(config.check(config.merge(config.DEFAULTS, dict(given))))
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def duty_to_wheel_rad_s(duty: int, forward: bool, max_wheel_rad_s: float, deadband_duty: int) -> float:
    """The wheel speed (rad/s, negative backwards) a PWM duty stands for: the inverse of the firmware's
    ``motors.duty_for_speed`` (exact up to the integer rounding of the duty)."""
    motors = firmware_modules()["motors"]
    return float(motors.speed_for_duty(duty, forward, max_wheel_rad_s, deadband_duty))


@dataclass(frozen=True)
class MotorState:
    """What the firmware last wrote to the H-bridge: duty 0-1023 and direction (True: forward) per wheel."""

    left_duty: int
    left_forward: bool
    right_duty: int
    right_forward: bool


class HostRover:
    """One rover's firmware on the host.

    ``config``: a config.json dict (``id`` and the sections to override; the firmware defaults fill the rest).
    ``broker_host``/``broker_port``: the MQTT broker; ``None`` runs without a link (feed messages with
    :meth:`deliver`). ``link_clock``: milliseconds for the link's keepalive and reconnect timing; defaults to the
    host's monotonic clock, so a simulation running faster or slower than real time does not upset the broker's
    keepalive. The control clock is the ``now_ms`` passed to :meth:`step`. ``on_status(payload)``: every rover
    status the firmware hands to the broker (rover status v2 bytes).
    """

    def __init__(
        self,
        config: Mapping[str, Any],
        broker_host: str | None = "127.0.0.1",
        broker_port: int = 1883,
        *,
        link_clock: Callable[[], int] | None = None,
        log: Callable[..., None] | None = None,
        on_status: Callable[[bytes], None] | None = None,
    ) -> None:
        fw = firmware_modules()
        cfg = copy.deepcopy(dict(config))
        if broker_host is not None:
            cfg.setdefault("broker", {})
            cfg["broker"] = {**cfg["broker"], "host": broker_host, "port": broker_port}
        elif not cfg.get("broker", {}).get("host"):
            cfg["broker"] = {**cfg.get("broker", {}), "host": "none"}
        self.config = check_rover_config(cfg)
        self.id: str = self.config["id"]
        self.log_lines: list[str] = []
        self._log = log if log is not None else self._remember
        self.motors = fw["motors"].Motors(self.config["motors"])
        self.rover = fw["rover"].Rover(self.config, self.motors, log=self._log)
        self.link = None
        self._link_clock = link_clock or _monotonic_ms
        if broker_host is not None:
            self.link = fw["link"].Link(
                self.config, self.rover.on_message, self.rover.on_connect, log=self._log, safe=self.motors.stop
            )
            self.rover.link = _ClockedLink(self.link, self._link_clock, on_status)

    def _remember(self, *args: object) -> None:
        self.log_lines.append(" ".join(str(a) for a in args))
        del self.log_lines[:-200]

    # -- stepping ------------------------------------------------------------------------------------------------
    def step(self, now_ms: int) -> None:
        """One firmware loop iteration at ``now_ms`` (receive what arrived, decide, write the motors)."""
        self.rover.step(now_ms & ((1 << 30) - 1))

    def deliver(self, topic: str | bytes, payload: bytes, now_ms: int | None = None) -> None:
        """Hand a message to the firmware as the MQTT callback would (no broker); stamped with ``now_ms`` or the
        time of the last step."""
        if now_ms is not None:
            self.rover._now = now_ms & ((1 << 30) - 1)
        self.rover.on_message(topic.encode() if isinstance(topic, str) else topic, payload)

    def pump(self, until: Callable[[], bool], timeout_s: float = 1.0, now_ms: int | None = None) -> bool:
        """Drain the broker link (real time) until ``until()`` holds or ``timeout_s`` passes, without a control
        step; messages are stamped with ``now_ms`` (default: the last step's time). Returns ``until()``."""
        if self.link is None:
            return until()
        if now_ms is not None:
            self.rover._now = now_ms & ((1 << 30) - 1)
        deadline = time.monotonic() + timeout_s
        while not until():
            if time.monotonic() > deadline:
                return False
            self.link.poll(self._link_clock())
            time.sleep(0.0005)
        return True

    def last_seq(self, rover_id: str) -> int | None:
        """Seq of the newest pose this rover has received from ``rover_id`` (None: none yet)."""
        r = self.rover
        r.flush()  # poses wait as bytes until the next step; parse them now
        for slot, rid in enumerate(r._ids):
            if rid == rover_id:
                return int(r._seq[slot])
        return None

    # -- outputs -------------------------------------------------------------------------------------------------
    @property
    def motor_state(self) -> MotorState:
        m = self.motors
        return MotorState(int(m.left.duty), bool(m.left.forward), int(m.right.duty), bool(m.right.forward))

    @property
    def wheel_speeds_rad_s(self) -> tuple[float, float]:
        """(left, right) wheel speeds the duties stand for, rad/s (the duty model inverted)."""
        left, right = self.motors.speeds()
        return float(left), float(right)

    @property
    def wheel_speeds_cm_s(self) -> tuple[float, float]:
        """(left, right) wheel rim speeds, cm/s."""
        r = float(self.config["geometry"]["wheel_radius_cm"])
        left, right = self.wheel_speeds_rad_s
        return left * r, right * r

    @property
    def command(self) -> dict[str, float]:
        """The law's output this step: look-ahead velocity ux, uy (cm/s), v (cm/s), w (rad/s), wheels (rad/s)."""
        c = self.rover.command
        return {"ux": c[0], "uy": c[1], "v": c[2], "w": c[3], "left_rad_s": c[4], "right_rad_s": c[5]}

    @property
    def halt(self) -> str:
        """Why the motors are stopped (``none`` when driving, ``probe`` when learning the heading)."""
        return str(self.rover.halt)

    @property
    def connected(self) -> bool:
        return bool(self.link is not None and self.link.up)

    def check_broker(self) -> None:
        """Connect once with the firmware's own MQTT client, credentials and timeout, then disconnect cleanly:
        :class:`BrokerError` when the broker cannot be reached or refuses this rover (the firmware itself would
        retry for ever, as a rover must)."""
        if self.link is None:
            return
        b = self.config["broker"]
        where = f"mqtt://{b['host']}:{b['port']}"
        client = self.link.client
        try:
            client.connect(True, b["timeout_s"])
        except OSError as exc:
            raise BrokerError(f"cannot reach broker {where}: {exc.strerror or exc}") from None
        except sys.modules["umqtt.simple"].MQTTException as exc:
            code = exc.args[0]
            reason = CONNACK_REFUSALS.get(code, f"no valid CONNACK ({code})")
            hint = " (check the rover's user and password)" if code in (4, 5) else ""
            raise BrokerError(
                f"broker {where} refused rover {self.id!r} (user {b['user']!r}): {reason}{hint}"
            ) from None
        client.disconnect()

    # -- teardown ------------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Clean disconnect: publishes the offline status (a clean DISCONNECT fires no last will)."""
        self.motors.stop()
        if self.link is not None:
            self.link.close(self.rover.status_payload("offline"))

    def crash(self) -> None:
        """Drop the TCP connection without DISCONNECT, as a rover losing power would: the broker sends the will."""
        self.motors.stop()
        if self.link is not None and self.link.client.sock is not None:
            self.link.client.sock.close()
            self.link.up = False


CONNACK_REFUSALS = {
    1: "unacceptable protocol version",
    2: "client id rejected",
    3: "server unavailable",
    4: "bad user name or password",
    5: "not authorised",
}


def _monotonic_ms() -> int:
    return int(time.monotonic() * 1000) & ((1 << 30) - 1)


class _ClockedLink:
    """The firmware's Link, timed by the host's clock instead of the simulation's (keepalive, backoff); statuses
    handed to the broker are shown to ``on_status`` too."""

    def __init__(self, link: Any, clock: Callable[[], int], on_status: Callable[[bytes], None] | None) -> None:
        self._link = link
        self._clock = clock
        self._on_status = on_status

    def poll(self, now_ms: int) -> bool:
        return bool(self._link.poll(self._clock()))

    @property
    def up(self) -> bool:
        return bool(self._link.up)

    def publish_status(self, payload: bytes) -> None:
        self._link.publish_status(payload)
        if self._on_status is not None and self._link.up:
            self._on_status(payload)
