"""The twin's rovers: each one the real firmware (:class:`edge.rover_host.HostRover`) on its own thread in real
time, its own MQTT client with its own login, and a station interface the lab can take its access point from.

The firmware's motor duties are the only thing the simulated world reads from a rover (:attr:`TwinRover.wheels`),
as wheels read the H-bridge: poses and formations reach the firmware through the broker, as on the floor.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from edge.messages import parse_rover_status
from edge.rover_host import HostRover

TICKS_MASK = (1 << 30) - 1  # the ESP8266's time.ticks_ms() wraps at 2**30


class Station:
    """The rover's ``network.WLAN`` station interface in the lab: associated, except while :meth:`drop` holds its
    access point away (the firmware then sees Wi-Fi gone, as on the chip, and reconnects when it is back)."""

    PM_NONE = 0
    PM_PERFORMANCE = 1
    PM_POWERSAVE = 2

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._active = True
        self._away_until = -1.0
        self.pm = self.PM_NONE

    def active(self, is_active: bool | None = None) -> bool | None:
        if is_active is None:
            return self._active
        self._active = bool(is_active)
        return None

    def config(self, **kwargs: Any) -> None:
        self.pm = kwargs.get("pm", self.pm)

    def connect(self, ssid: str | None = None, key: str | None = None) -> None:
        self._active = True

    def disconnect(self) -> None:
        self._active = False

    def isconnected(self) -> bool:
        return self._active and self._clock() >= self._away_until

    def drop(self, seconds: float) -> None:
        """No access point for ``seconds`` from now."""
        self._away_until = max(self._away_until, self._clock() + seconds)


class TwinRover:
    """One rover's firmware, stepped at its ``control.period_ms`` in real time on its own thread.

    ``on_event(rover id, text)``: the firmware's link and halt changes, and each status it publishes that says
    something new.
    """

    def __init__(
        self,
        config: Mapping[str, Any],
        *,
        on_event: Callable[[str, str], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.id = str(config["id"])
        self.on_event = on_event
        self.clock = clock
        self.period_s = int(config["control"]["period_ms"]) / 1000.0
        broker = config["broker"]
        self.host = HostRover(
            config, broker["host"], int(broker["port"]), log=self._log, on_status=self._status, link_clock=self._ms
        )
        self.station = Station(clock)
        if self.host.link is not None:
            self.host.link.wlan = self.station  # what the firmware asks whether it has Wi-Fi
        self.steps = 0
        self._said: tuple[str, str, str | None, int | None] | None = None
        self._thread: threading.Thread | None = None

    def _ms(self) -> int:
        return int(self.clock() * 1000) & TICKS_MASK

    def _log(self, *args: object) -> None:
        text = " ".join(str(a) for a in args)
        if text.startswith(("broker", "halt", "wifi")):
            self.on_event(self.id, text)

    def _status(self, payload: bytes) -> None:
        try:
            status = parse_rover_status(payload)
        except Exception as exc:  # the firmware broke the contract: say so
            self.on_event(self.id, f"status breaks the contract: {exc}")
            return
        key = (status.state, status.halt, status.formation, status.seq)
        if key != self._said:
            self._said = key
            applies = "no formation" if status.formation is None else f"{status.formation} (seq {status.seq})"
            self.on_event(self.id, f"reports {status.state}, halt {status.halt}, applies {applies}")

    @property
    def wheels_cm_s(self) -> tuple[float, float]:
        """(left, right) rim speeds the motor duties stand for (the duty model inverted)."""
        return self.host.wheel_speeds_cm_s

    @property
    def connected(self) -> bool:
        return self.host.connected

    def start(self, stop: threading.Event) -> TwinRover:
        self._thread = threading.Thread(target=self._run, args=(stop,), name=f"rover-{self.id}", daemon=True)
        self._thread.start()
        return self

    def _run(self, stop: threading.Event) -> None:
        due = self.clock()
        while not stop.is_set():
            self.host.step(self._ms())
            self.steps += 1
            due += self.period_s
            late = self.clock() - due
            if late > self.period_s:  # fell behind (a loaded computer): carry on from now, as the board's loop would
                due = self.clock()
            elif stop.wait(max(0.0, -late)):
                break

    def close(self, timeout_s: float = 5.0) -> None:
        """After ``stop`` is set: the loop ends, then motors off, the offline status, a clean disconnect."""
        if self._thread is not None:
            self._thread.join(timeout_s)
        self.host.close()
