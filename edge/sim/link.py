"""The Wi-Fi hop between the broker and one rover, as the rover's firmware experiences it: pure, seeded, per rover.

MQTT runs over TCP, so a rover never sees a QoS 0 pose "lost" on the air. A frame the radio loses (after the MAC's
own retries) is sent again by TCP, and every segment behind it waits for it (head-of-line blocking): on a live
connection, loss shows up as *delay*, in order. Poses are lost for good only when the connection itself goes: an
outage long enough for the station to lose its access point, after which the firmware opens a new connection and
whatever the broker sent to the old one (QoS 0, clean session) goes nowhere. :class:`LinkModel` decides, for every
MQTT packet sent at time ``t`` on one TCP connection in one direction, when it reaches the other end, or that it
never does.

The parts, each with the published measurement it follows:

* **Delay of a frame on the air** (queueing, contention, the MAC's retries and rate fall-back): a log-normal body,
  median ``latency_ms``, 90th percentile ``latency_ms + jitter_ms``, and a power-law tail: ``TAIL_SHARE`` of the
  frames take between the body's 90th percentile and ``tail_ms`` (density ~ 1/x², a Pareto tail with alpha 1,
  truncated). Why not one log-normal: Wi-Fi latency measured on 47,000 campus devices has a long tail, 90th
  percentile ~20 ms and 99th ~250 ms (Sui et al., "Characterizing and Improving WiFi Latency in Large-Scale
  Operational Networks", MobiSys 2016), far heavier than a log-normal with that 90th percentile; and 802.11's binary
  exponential backoff gives a truncated power-law tail of the access delay (Sakurai & Vu, "MAC Access Delay of IEEE
  802.11 DCF", IEEE Trans. Wireless Commun. 6(5), 2007).
* **Bursty loss** (Gilbert-Elliott, in continuous time): the channel alternates good spells and bad spells
  (exponential, mean ``burst_ms``); it is bad ``loss_pct`` of the time, and a frame sent while it is bad is lost.
  Loss on indoor 802.11 comes in bursts separated by long clean gaps; two states are the simplest model with
  bursts (measured burst lengths have heavier tails than two states give: Cardoso & de Rezende, IEEE Commun.
  Lett. 13(6), 2009; the outages below carry the long ones).
* **Outages** (the access point out of reach: a rover behind another, a microwave oven, a neighbour's burst of
  traffic): ``outages_per_min`` on average (Poisson), each ``outage_min_s``-``outage_max_s`` long (log-uniform: short
  ones are commoner). Nothing crosses, either way.
* **TCP** turns loss into delay. Downlink (the broker's Linux TCP): a lost segment is sent again after about two
  round trips (fast retransmit or the tail-loss probe; the pose stream keeps segments flowing), and if that is lost
  too, on the retransmission timer (200 ms + RTT, doubling each time). After a timeout the sender sends nothing new
  until the lost segment is through, then the backlog at once: so an outage ends for the rover at the first
  retransmission after it, and TCP's backoff stretches a 1 s outage to up to 1.6-1.8 s. Uplink (the rover's lwIP, a
  status now and then, a ping every 5 s): no fast retransmit for so sparse a stream; the timer, about 1 s.
* **Association**: an outage longer than ``drop_s`` costs the station its access point (the ESP8266 reports a
  beacon timeout after ~6 s without beacons and disassociates after ~2.5 s of probes: espressif/ESP8266_RTOS_SDK
  #1222); :meth:`LinkModel.associated` turns False then, the firmware sees Wi-Fi gone and drops its connection,
  and every packet not through by then is lost. It is associated again ``rejoin_s`` after the access point is back
  (scan, authentication, DHCP); the firmware connects, subscribes and gets the retained formation.

Randomness: the channel's spells and outages are a function of time alone (drawn forward from the seed); a packet's
air delay is drawn from a hash of the seed, the connection, its flow (topic) and its number within that flow, so one
pose gets the same delay whatever control packets were interleaved with it.
"""

from __future__ import annotations

import bisect
import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from statistics import NormalDist
from typing import Literal

import numpy as np

from edge.errors import ConfigError

Direction = Literal["down", "up"]
ChannelState = Literal["good", "bad", "out"]

TAIL_SHARE = 0.02  # frames that take the power-law tail
_Z90 = NormalDist().inv_cdf(0.9)
_STD_NORMAL = NormalDist()
_MAX_ATTEMPTS = 40


@dataclass(frozen=True)
class LinkSettings:
    """One Wi-Fi link, in the units a user gives (see the module docstring for what each part models).

    The string form (``--link``) is a preset name and/or ``key=value`` items, e.g. ``typical``,
    ``poor,outages=0``, ``latency=10ms,jitter=10ms,tail=150ms,loss=2%,burst=30ms,outages=2/min,outage=0.3s-2s``.
    """

    latency_ms: float = 0.0  # median air delay of one frame
    jitter_ms: float = 0.0  # 90th percentile minus the median
    tail_ms: float = 0.0  # longest delay of the power-law tail (0: no tail)
    loss_pct: float = 0.0  # share of the time the channel is bad (frames sent then are lost)
    burst_ms: float = 30.0  # mean length of a bad spell
    outages_per_min: float = 0.0
    outage_min_s: float = 0.3
    outage_max_s: float = 2.0
    drop_s: float = 8.5  # an outage this long loses the association (the connection)
    rejoin_s: float = 1.5  # associated again this long after the access point is back

    def __post_init__(self) -> None:
        checks = (
            ("latency", 0.0 <= self.latency_ms <= 1000.0, "0-1000 ms"),
            ("jitter", 0.0 <= self.jitter_ms <= 1000.0 and (self.jitter_ms == 0 or self.latency_ms > 0), "0-1000 ms"),
            ("tail", self.tail_ms == 0 or self.latency_ms + self.jitter_ms < self.tail_ms <= 10000.0, "above"),
            ("loss", 0.0 <= self.loss_pct <= 50.0, "0-50 %"),
            ("burst", 0.1 <= self.burst_ms <= 10000.0, "0.1 ms-10 s"),
            ("outages", 0.0 <= self.outages_per_min <= 60.0, "0-60 per minute"),
            ("outage", 0.01 <= self.outage_min_s <= self.outage_max_s <= 600.0, "0.01-600 s, shortest first"),
            ("drop", 0.1 <= self.drop_s <= 3600.0, "0.1 s-1 h"),
            ("rejoin", 0.0 <= self.rejoin_s <= 600.0, "0-600 s"),
        )
        for key, ok, allowed in checks:
            if not ok:
                if key == "tail":
                    allowed = f"0 (none) or above latency + jitter ({self.latency_ms + self.jitter_ms:g} ms)"
                if key == "jitter" and self.latency_ms == 0:
                    allowed = "0 when latency is 0"
                raise ConfigError(f"link {key}={_format(self, key)}: must be {allowed}")

    @classmethod
    def parse(cls, text: str) -> LinkSettings:
        """``typical``, ``poor,loss=3%``, ``latency=10ms,jitter=5ms,...``: ConfigError names the item at fault."""
        items = [item.strip() for item in text.split(",") if item.strip()]
        if not items:
            raise ConfigError("link: empty; give a preset (" + ", ".join(PRESETS) + ") or key=value items")
        base = cls()
        if "=" not in items[0]:
            name = items.pop(0).lower()
            if name not in PRESETS:
                raise ConfigError(f"link {name!r}: unknown preset (use {', '.join(PRESETS)}) or key=value items")
            base = PRESETS[name]
        values: dict[str, float] = {}
        for item in items:
            key, sep, value = item.partition("=")
            key = key.strip().lower()
            if not sep or key not in _KEYS:
                raise ConfigError(f"link {item!r}: expected key=value with key one of {', '.join(_KEYS)}")
            values.update(_parse_value(key, value.strip()))
        return replace(base, **values)

    def __str__(self) -> str:
        return ",".join(f"{key}={_format(self, key)}" for key in _KEYS)

    @property
    def is_wire(self) -> bool:
        """Nothing delayed, lost or cut: every message reaches the rover at once."""
        return self.latency_ms == 0 and self.tail_ms == 0 and self.loss_pct == 0 and self.outages_per_min == 0


# key -> (field, unit of the field); "outage" is a range and fills two fields.
_KEYS: dict[str, tuple[str, str]] = {
    "latency": ("latency_ms", "ms"),
    "jitter": ("jitter_ms", "ms"),
    "tail": ("tail_ms", "ms"),
    "loss": ("loss_pct", "%"),
    "burst": ("burst_ms", "ms"),
    "outages": ("outages_per_min", "/min"),
    "outage": ("outage_min_s", "s"),
    "drop": ("drop_s", "s"),
    "rejoin": ("rejoin_s", "s"),
}
_NUMBER = r"(\d+(?:\.\d*)?|\.\d+)"


def _parse_value(key: str, value: str) -> dict[str, float]:
    name, unit = _KEYS[key]
    if key == "outage":
        m = re.fullmatch(rf"{_NUMBER}\s*(ms|s)?\s*(?:-\s*{_NUMBER}\s*(ms|s))?", value)
        if m is None or (m.group(2) is None and m.group(3) is None and m.group(1) != "0"):
            raise ConfigError(f"link outage={value}: expected a duration or a range, e.g. 0.3s-2s or 0.3-2s")
        lo_unit = m.group(2) or m.group(4) or "s"
        lo = _scaled(float(m.group(1)), lo_unit, "s")
        hi = lo if m.group(3) is None else _scaled(float(m.group(3)), m.group(4), "s")
        return {"outage_min_s": lo, "outage_max_s": hi}
    units = {"ms": ("ms", "s"), "%": ("%",), "/min": ("/min", "/s"), "s": ("s", "ms")}[unit]
    m = re.fullmatch(rf"{_NUMBER}\s*({'|'.join(re.escape(u) for u in units)})?", value)
    if m is None or (m.group(2) is None and float(m.group(1)) != 0.0):
        example = {"ms": "10ms", "%": "2%", "/min": "2/min", "s": "1.5s"}[unit]
        raise ConfigError(f"link {key}={value}: expected a number with its unit, e.g. {key}={example}")
    return {name: _scaled(float(m.group(1)), m.group(2) or unit, unit)}


def _scaled(v: float, given: str, wanted: str) -> float:
    if (given, wanted) == ("ms", "s"):
        return v / 1000.0
    factor = {("s", "ms"): 1000.0, ("/s", "/min"): 60.0}.get((given, wanted), 1.0)
    return round(v * factor, 9)  # 0.15 s is 150 ms, not 150.00000000000003


def _format(s: LinkSettings, key: str) -> str:
    def num(v: float) -> str:
        return format(v, ".12g")

    if key == "outage":
        return f"{num(s.outage_min_s)}s-{num(s.outage_max_s)}s"
    name, unit = _KEYS[key]
    return num(getattr(s, name)) + unit


PRESETS: dict[str, LinkSettings] = {
    # Every message at the rover's next control step: the loopback broker of the first experiments.
    "wire": LinkSettings(),
    # One access point in the room, little else on the channel.
    "good": LinkSettings(latency_ms=5.0, jitter_ms=3.0, tail_ms=50.0, loss_pct=1.0, burst_ms=20.0, outages_per_min=0.5),
    # A lab network shared with laptops and phones: 90th percentile 20 ms as measured by Sui et al.
    "typical": LinkSettings(
        latency_ms=10.0, jitter_ms=10.0, tail_ms=150.0, loss_pct=2.0, burst_ms=30.0, outages_per_min=1.0
    ),
    # A crowded 2.4 GHz band, the access point far or behind a wall.
    "poor": LinkSettings(
        latency_ms=20.0, jitter_ms=30.0, tail_ms=150.0, loss_pct=5.0, burst_ms=40.0, outages_per_min=3.0
    ),
}


@dataclass(frozen=True)
class Outage:
    """The access point out of reach from ``start_s`` to ``end_s``; ``dropped``: long enough to lose the
    association, which is back at ``rejoin_at_s``."""

    start_s: float
    end_s: float
    dropped: bool
    rejoin_at_s: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True)
class Retransmit:
    """When a TCP sender sends a lost segment again: ``first_s`` after the loss, then ``rto_s`` later, doubling."""

    first_s: float
    rto_s: float
    rto_max_s: float = 120.0

    def attempts(self, t0_s: float) -> list[float]:
        """Transmission times of one segment first sent at ``t0_s`` (the first ``_MAX_ATTEMPTS``)."""
        out = [t0_s, t0_s + self.first_s]
        wait = self.rto_s
        while len(out) < _MAX_ATTEMPTS:
            out.append(out[-1] + wait)
            wait = min(2.0 * wait, self.rto_max_s)
        return out


class _Channel:
    """The radio channel's state as a function of time: good and bad spells, outages on top, drawn forward."""

    def __init__(self, settings: LinkSettings, rng_spells: np.random.Generator, rng_outages: np.random.Generator):
        self._s = settings
        self._rng_spells = rng_spells
        self._rng_outages = rng_outages
        self._bad_starts: list[float] = []
        self._bad_ends: list[float] = []
        self._spells_until = 0.0
        self._outages: list[Outage] = []
        self._out_starts: list[float] = []
        self._outages_until = 0.0
        p = settings.loss_pct / 100.0
        self._bad_mean_s = settings.burst_ms / 1000.0
        self._good_mean_s = self._bad_mean_s * (1.0 - p) / p if p > 0 else math.inf
        if p > 0 and rng_spells.random() < p:  # start in the stationary distribution
            self._append_bad(0.0)

    def _append_bad(self, start: float) -> None:
        end = start + float(self._rng_spells.exponential(self._bad_mean_s))
        self._bad_starts.append(start)
        self._bad_ends.append(end)
        self._spells_until = end

    def _extend(self, t_s: float) -> None:
        while self._spells_until <= t_s and math.isfinite(self._good_mean_s):
            self._append_bad(self._spells_until + float(self._rng_spells.exponential(self._good_mean_s)))
        if self._s.outages_per_min <= 0:
            return
        s = self._s
        while self._outages_until <= t_s:
            start = self._outages_until + float(self._rng_outages.exponential(60.0 / s.outages_per_min))
            lo, hi = math.log(s.outage_min_s), math.log(s.outage_max_s)
            duration = math.exp(float(self._rng_outages.uniform(lo, hi))) if hi > lo else s.outage_min_s
            end = start + duration
            dropped = duration > s.drop_s
            self._outages.append(Outage(start, end, dropped, end + s.rejoin_s if dropped else end))
            self._out_starts.append(start)
            self._outages_until = end

    def outage_at(self, t_s: float) -> Outage | None:
        self._extend(t_s)
        k = bisect.bisect_right(self._out_starts, t_s) - 1
        if k >= 0 and t_s < self._outages[k].end_s:
            return self._outages[k]
        return None

    def state(self, t_s: float) -> ChannelState:
        if self.outage_at(t_s) is not None:
            return "out"
        k = bisect.bisect_right(self._bad_starts, t_s) - 1
        if k >= 0 and t_s < self._bad_ends[k]:
            return "bad"
        return "good"

    def outages(self, until_s: float) -> list[Outage]:
        self._extend(until_s)
        return [o for o in self._outages if o.start_s < until_s]

    def drop_between(self, t0_s: float, t1_s: float) -> float | None:
        """The first moment in [t0, t1] the station is without its access point (a long outage's drop), if any."""
        for o in self.outages(t1_s):
            if o.dropped and o.start_s + self._s.drop_s <= t1_s and o.rejoin_at_s > t0_s:
                return max(o.start_s + self._s.drop_s, t0_s)
        return None


class LinkModel:
    """One rover's Wi-Fi link: ``LinkModel(settings, seed)``; :meth:`connection` for each TCP connection made over it.

    ``seed``: an int or a sequence of ints (the experiment's seed and the rover's index, say).
    """

    def __init__(self, settings: LinkSettings, seed: int | Sequence[int]) -> None:
        self.settings = settings
        self._seed = (int(seed),) if isinstance(seed, int) else tuple(int(s) for s in seed)
        spells, outages = np.random.SeedSequence([*self._seed, 0x11F1]).spawn(2)
        self._channel = _Channel(settings, np.random.default_rng(spells), np.random.default_rng(outages))
        self._connections = 0
        rtt_s = 2.0 * settings.latency_ms / 1000.0  # one median each way
        self.retransmit: dict[Direction, Retransmit] = {
            "down": Retransmit(first_s=max(2.0 * rtt_s, 0.01), rto_s=0.2 + rtt_s),
            "up": Retransmit(first_s=1.0, rto_s=1.0),
        }

    def connection(self) -> tuple[Stream, Stream]:
        """The (downlink, uplink) streams of a new TCP connection over this link."""
        self._connections += 1
        return Stream(self, "down", self._connections), Stream(self, "up", self._connections)

    def state(self, t_s: float) -> ChannelState:
        """The channel at ``t_s``: good, bad (frames lost) or out (an outage)."""
        return self._channel.state(t_s)

    def associated(self, t_s: float) -> bool:
        """Whether the station has its access point at ``t_s`` (False from ``drop_s`` into a long outage until
        ``rejoin_s`` after it)."""
        return self._channel.drop_between(t_s, t_s) is None

    def outages(self, until_s: float) -> list[Outage]:
        """Every outage that starts before ``until_s``."""
        return self._channel.outages(until_s)

    def air_delay_s(self, u_tail: float, u: float) -> float:
        """The air delay for two uniforms in [0, 1): the log-normal body or, for ``u_tail < TAIL_SHARE``, the
        truncated power-law tail."""
        s = self.settings
        median = s.latency_ms / 1000.0
        if median == 0:
            return 0.0
        p90 = (s.latency_ms + s.jitter_ms) / 1000.0
        tail = s.tail_ms / 1000.0
        if tail > p90 and u_tail < TAIL_SHARE:
            return 1.0 / (1.0 / p90 - u * (1.0 / p90 - 1.0 / tail))  # Pareto, alpha 1, on [p90, tail]
        sigma = math.log(p90 / median) / _Z90
        delay = median * math.exp(sigma * _STD_NORMAL.inv_cdf(min(max(u, 1e-12), 1.0 - 1e-12)))
        return min(delay, tail) if tail > 0 else delay

    def _uniforms(self, key: tuple[object, ...]) -> tuple[float, float]:
        digest = hashlib.blake2b(repr((self._seed, *key)).encode(), digest_size=16).digest()
        return int.from_bytes(digest[:8]) / 2.0**64, int.from_bytes(digest[8:]) / 2.0**64

    def _drop_between(self, t0_s: float, t1_s: float) -> float | None:
        return self._channel.drop_between(t0_s, t1_s)


class Stream:
    """One direction of one TCP connection: in order, every loss turned into delay."""

    def __init__(self, model: LinkModel, direction: Direction, connection: int) -> None:
        self.model = model
        self.direction = direction
        self._connection = connection
        self._timers = model.retransmit[direction]
        self._last_due = -math.inf
        self._gate = -math.inf  # after a retransmission timeout nothing new is sent before this
        self._counts: dict[str, int] = {}
        self.retransmitted = 0  # packets that needed at least one retransmission
        self.lost = 0  # packets that never got through (the association went first)

    def deliver(self, sent_s: float, flow: str = "") -> float | None:
        """When a packet handed to TCP at ``sent_s`` reaches the other end, or None: the association is lost first.

        ``flow``: what the packet belongs to (an MQTT topic, a packet type); its delay draw is keyed on it."""
        n = self._counts.get(flow, 0)
        self._counts[flow] = n + 1
        u_tail, u = self.model._uniforms((self.direction, self._connection, flow, n))
        air = self.model.air_delay_s(u_tail, u)
        t0 = max(sent_s, self._gate)
        attempts = self._timers.attempts(t0)
        k = next((k for k, t in enumerate(attempts) if self.model.state(t) == "good"), None)
        if k is None:
            self.lost += 1
            return None
        t = attempts[k]
        if k:
            self.retransmitted += 1
        if k >= 2:
            self._gate = t
        due = max(t + air, self._last_due)
        if self.model._drop_between(sent_s, due) is not None:
            self.lost += 1
            return None
        self._last_due = due
        return due
