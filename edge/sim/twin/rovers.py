"""The twin's rovers: each one the real firmware (:class:`edge.rover_host.HostRover`) on its own thread in real
time, its own MQTT client with its own login, behind its own Wi-Fi link.

The link is the closed-loop experiments' (:mod:`edge.sim.link`, :mod:`edge.sim.relay`): a TCP relay between the
firmware and the broker hands over each MQTT packet when the rover's :class:`~edge.sim.link.LinkModel` says, here on
the real clock (:meth:`LinkRelay.release` before each control step: the firmware reads what has arrived by its
step's time), and the firmware's station interface reports the association the model gives. ``--link wire`` (the
default) delays nothing; a fault (:meth:`TwinRover.drop_wifi`) is an outage added to the model, so it does what an
outage does: nothing crosses either way, TCP sends again after it (the backlog arrives at once), and an outage
longer than the link's ``drop_s`` costs the association (the firmware drops its connection and makes a new one).

The firmware's motor duties are the only thing the simulated world reads from a rover (:attr:`TwinRover.wheels_cm_s`),
as wheels read the H-bridge: poses and formations reach the firmware through the broker, as on the floor.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from edge.messages import parse_rover_status
from edge.rover_host import HostRover
from edge.sim.link import LinkModel, LinkSettings, Outage
from edge.sim.relay import LinkRelay, Station

TICKS_MASK = (1 << 30) - 1  # the ESP8266's time.ticks_ms() wraps at 2**30
KEEP_DELAYS = 10_000  # pose air delays each relay keeps (the newest), for the lab's figures


class FaultyLink(LinkModel):
    """A rover's :class:`LinkModel` with outages an operator adds (:meth:`force`) on top of the modelled ones."""

    def __init__(self, settings: LinkSettings, seed: int | Sequence[int]) -> None:
        super().__init__(settings, seed)
        self.forced: list[Outage] = []
        self._lock = threading.Lock()

    def force(self, start_s: float, seconds: float) -> Outage:
        """The access point out of reach from ``start_s`` for ``seconds`` (associated again ``rejoin_s`` after it
        when it was long enough to lose the association)."""
        s = self.settings
        dropped = seconds > s.drop_s
        end = start_s + seconds
        outage = Outage(start_s, end, dropped, end + s.rejoin_s if dropped else end)
        with self._lock:
            bisect.insort(self.forced, outage, key=lambda o: o.start_s)
        return outage

    def _forced_at(self, t_s: float) -> Outage | None:
        with self._lock:
            return next((o for o in self.forced if o.start_s <= t_s < o.end_s), None)

    def _forced_drop(self, t0_s: float, t1_s: float) -> float | None:
        drop_s = self.settings.drop_s
        with self._lock:
            for o in self.forced:
                if o.dropped and o.start_s + drop_s <= t1_s and o.rejoin_at_s > t0_s:
                    return max(o.start_s + drop_s, t0_s)
        return None

    def state(self, t_s: float) -> Any:
        return "out" if self._forced_at(t_s) is not None else super().state(t_s)

    def associated(self, t_s: float) -> bool:
        return self._forced_drop(t_s, t_s) is None and super().associated(t_s)

    def outages(self, until_s: float) -> list[Outage]:
        with self._lock:
            forced = [o for o in self.forced if o.start_s < until_s]
        return sorted([*super().outages(until_s), *forced], key=lambda o: o.start_s)

    def _drop_between(self, t0_s: float, t1_s: float) -> float | None:
        drops = [d for d in (self._forced_drop(t0_s, t1_s), super()._drop_between(t0_s, t1_s)) if d is not None]
        return min(drops) if drops else None


class TwinRover:
    """One rover's firmware, stepped at its ``control.period_ms`` in real time on its own thread, connected to its
    broker (``config["broker"]``) through its link.

    ``on_event(rover id, text)``: the firmware's link and halt changes, and each status it publishes that says
    something new.
    """

    def __init__(
        self,
        config: Mapping[str, Any],
        *,
        link: LinkSettings,
        seed: int | Sequence[int],
        on_event: Callable[[str, str], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.id = str(config["id"])
        self.on_event = on_event
        self.clock = clock
        self.period_s = int(config["control"]["period_ms"]) / 1000.0
        self._t0 = clock()
        self.model = FaultyLink(link, seed)
        broker = config["broker"]
        self.relay = LinkRelay(str(broker["host"]), int(broker["port"]), self.model, self.link_time_s).start()
        self.relay.transparent = False  # real time from the start: the link is modelled from the first packet
        self.host = HostRover(config, "127.0.0.1", self.relay.port, log=self._log, on_status=self._status)
        if self.host.link is not None:
            self.host.link.wlan = Station(self.model, self.link_time_s)  # what the firmware asks about Wi-Fi
        self.steps = 0
        self.last_fresh_s: float | None = None  # when the firmware last got a new pose of its own (clock, s)
        self._own_seq: int | None = None
        self._own_changed = threading.Condition()
        self._said: tuple[str, str, str | None, int | None] | None = None
        self._thread: threading.Thread | None = None

    def link_time_s(self) -> float:
        """The link model's time: seconds since this rover was switched on."""
        return self.clock() - self._t0

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

    def drop_wifi(self, seconds: float) -> Outage:
        """The access point out of reach for ``seconds`` from now (see the module docstring)."""
        return self.model.force(self.link_time_s(), seconds)

    def wait_own_pose(self, seq: int, timeout_s: float) -> bool:
        """Until the firmware, on its own thread, has taken its own pose number ``seq`` (False after
        ``timeout_s``). The firmware is not touched from the caller's thread: it runs on its own."""
        with self._own_changed:
            return self._own_changed.wait_for(lambda: self._own_seq == seq, timeout_s)

    def pose_delays_s(self) -> list[float]:
        """Air delays of the newest poses this rover received (broker to firmware, s)."""
        delays = self.relay.log.pose_delays_s
        del delays[:-KEEP_DELAYS]  # a lab runs for hours: keep the newest
        return list(delays)

    def cpu_s(self) -> tuple[float, float]:
        """CPU seconds used so far by (this rover's firmware thread, its link's relay thread)."""
        return thread_cpu_s(self._thread), thread_cpu_s(self.relay.thread)

    def start(self, stop: threading.Event) -> TwinRover:
        self._thread = threading.Thread(target=self._run, args=(stop,), name=f"rover-{self.id}", daemon=True)
        self._thread.start()
        return self

    def _run(self, stop: threading.Event) -> None:
        due = self.clock()
        while not stop.is_set():
            self.relay.release(self.link_time_s())  # what the link delivered by now, then the control step
            self.host.step(int(self.clock() * 1000) & TICKS_MASK)
            self.steps += 1
            seq = self.host.last_seq(self.id)
            if seq != self._own_seq:
                with self._own_changed:
                    self._own_seq, self.last_fresh_s = seq, self.clock()
                    self._own_changed.notify_all()
            due += self.period_s
            late = self.clock() - due
            if late > self.period_s:  # fell behind (a loaded computer): carry on from now, as the board's loop would
                due = self.clock()
            elif stop.wait(max(0.0, -late)):
                break

    def close(self, timeout_s: float = 5.0) -> None:
        """After ``stop`` is set: the loop ends, then motors off, the offline status, a clean disconnect (through
        the link, which then closes)."""
        if self._thread is not None:
            self._thread.join(timeout_s)
        self.host.close()
        self.relay.release(self.link_time_s() + 60.0)  # the goodbye crosses the link however slow it is
        self.relay.close()


def thread_cpu_s(thread: threading.Thread | None) -> float:
    """CPU seconds a running thread has used (0 when it is not running): for what each part of the lab costs."""
    if thread is None or thread.ident is None or not thread.is_alive():
        return 0.0
    try:
        return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
    except (OSError, ProcessLookupError):  # it ended meanwhile
        return 0.0
