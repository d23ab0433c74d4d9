"""The rovers' half of the closed loop: a broker, and one firmware per rover behind its own Wi-Fi link.

Each rover is the real firmware (:class:`edge.rover_host.HostRover`: ``firmware/esp8266`` with host stand-ins for
the hardware) connected to the broker through a :class:`~edge.sim.relay.LinkRelay` that carries its MQTT
connection over the rover's :class:`~edge.sim.link.LinkModel`, and a :class:`~edge.sim.relay.Station` that tells
the firmware whether it has its access point.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from edge.config import BrokerTarget
from edge.errors import SimulationError
from edge.rover_host import HostRover, firmware_modules
from edge.sim.link import LinkModel, LinkSettings
from edge.sim.relay import LinkRelay, RelayLog, Station
from edge.sim.world import WheelCommand


class LoopBroker:
    """The broker a run talks through (:func:`edge.broker.clients.simulation_broker`, the edge's one rule for
    choosing it): an open embedded amqtt broker started here, or one at a URL."""

    def __init__(self, url: str | None) -> None:
        from edge.broker.clients import simulation_broker

        self._broker = simulation_broker(url)
        self.target: BrokerTarget = self._broker.target

    def kill(self) -> bool:
        """Stop the embedded broker (True); a broker at a URL is not ours to stop (False)."""
        if self._broker.started is None:
            return False
        self._broker.stop(timeout_s=5.0)
        return True

    def close(self) -> None:
        self.kill()


@dataclass
class MotorLog:
    """Every firmware step of one rover: time (ms, simulated), duties, directions, halt reason, and the seq of the
    newest pose of its own it had (None: none yet)."""

    t_ms: list[int] = field(default_factory=list)
    left_duty: list[int] = field(default_factory=list)
    right_duty: list[int] = field(default_factory=list)
    left_forward: list[bool] = field(default_factory=list)
    right_forward: list[bool] = field(default_factory=list)
    halt: list[str] = field(default_factory=list)
    own_seq: list[int | None] = field(default_factory=list)


class Fleet:
    """The rovers of a run, each behind its link. ``clock_s``: the simulated time in seconds."""

    def __init__(
        self,
        configs: Sequence[Mapping[str, Any]],
        broker: BrokerTarget,
        link: LinkSettings,
        seed: int,
        clock_s: Callable[[], float],
    ) -> None:
        self.rovers: dict[str, HostRover] = {}
        self.relays: dict[str, LinkRelay] = {}
        self.models: dict[str, LinkModel] = {}
        self.motors: dict[str, MotorLog] = {}
        self.fresh_ms: dict[str, list[int]] = {}  # when each rover got a new pose of its own (simulated ms)
        self.late: dict[str, int] = {}  # frames whose poses the broker had not sent it within the window
        self._own_seq: dict[str, int | None] = {}
        try:
            for k, cfg in enumerate(configs):
                rid = str(cfg["id"])
                model = LinkModel(link, (seed, k))
                relay = LinkRelay(broker.host, broker.port, model, clock_s).start()
                self.models[rid], self.relays[rid] = model, relay
                # The firmware's link keeps time on the simulated clock too (reconnect backoff, keepalive pings),
                # and its Wi-Fi is the modelled one.
                rover = HostRover(cfg, "127.0.0.1", relay.port, link_clock=partial(_ms, clock_s))
                if rover.link is not None:
                    rover.link.wlan = Station(model, clock_s)
                self.rovers[rid] = rover
                self.motors[rid] = MotorLog()
                self.fresh_ms[rid] = []
                self.late[rid] = 0
                self._own_seq[rid] = None
        except BaseException:
            self.close()
            raise

    @property
    def period_ms(self) -> int:
        """The firmware's control period (every rover runs the same)."""
        return int(next(iter(self.rovers.values())).config["control"]["period_ms"])

    def join(self, formation_seq: int, timeout_s: float = 10.0) -> None:
        """Connect every rover and wait until it applies the retained formation, before the clock starts (the
        links pass everything at once until then); from here on the links are modelled."""
        for rid, rover in self.rovers.items():
            rover.step(0)
            if not rover.pump(partial(_has_formation, rover, formation_seq), timeout_s=timeout_s):
                raise SimulationError(f"rover {rid} did not receive the formation within {timeout_s:g} s")
        for relay in self.relays.values():
            relay.transparent = False

    def await_poses(self, sent: Mapping[str, bytes], timeout_s: float) -> None:
        """Wait until the broker has sent every rover the newest pose of ``sent`` (topic -> payload); a rover it
        has not within ``timeout_s`` of real time counts this frame late (its relay stamps them when they come)."""
        for rid, relay in self.relays.items():
            if not relay.wait_for(sent, timeout_s):
                self.late[rid] += 1

    def step(self, now_ms: int) -> dict[str, WheelCommand]:
        """One control step of every rover at ``now_ms``: what its link delivered by then, then its firmware."""
        commands: dict[str, WheelCommand] = {}
        for rid, rover in self.rovers.items():
            self.relays[rid].release(now_ms / 1000.0)
            rover.step(now_ms)
            left, right = rover.wheel_speeds_cm_s
            commands[rid] = WheelCommand(left, right)
            m = rover.motor_state
            log = self.motors[rid]
            log.t_ms.append(now_ms)
            log.left_duty.append(m.left_duty)
            log.right_duty.append(m.right_duty)
            log.left_forward.append(m.left_forward)
            log.right_forward.append(m.right_forward)
            log.halt.append(rover.halt)
            seq = rover.last_seq(rid)
            log.own_seq.append(seq)
            if seq is not None and seq != self._own_seq[rid]:
                self._own_seq[rid] = seq
                self.fresh_ms[rid].append(now_ms)
        return commands

    def link_logs(self) -> dict[str, RelayLog]:
        return {rid: relay.log for rid, relay in self.relays.items()}

    def close(self) -> None:
        for relay in self.relays.values():
            relay.finish()
        for rover in self.rovers.values():
            rover.close()
        for relay in self.relays.values():
            relay.close()


def _ms(clock_s: Callable[[], float]) -> int:
    return int(clock_s() * 1000.0)


def _has_formation(rover: HostRover, seq: int) -> bool:
    f = rover.rover.formation
    return f is not None and int(f[firmware_modules()["msg"]._F_SEQ]) == seq
