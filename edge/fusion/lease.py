"""Who of several fusers publishes the poses: a lease decided by the order of one topic on one broker (pure).

Every fuser subscribes to ``ips/v1/fuser/lease`` on the central broker and applies its messages in the order the
broker delivers them, which is one order for every subscriber of one topic on one broker: a shared log. The state
is ``(holder, session, n)``; ``session`` is a random name the holder chose for its broker connection.

* ``beat (holder, session, n)``: the holder renews its lease every ``beat_s`` (retained); valid when holder and
  session match the state;
* ``claim (claimant, session, after=(holder, session, n))``: valid only when ``after`` is the state at the claim's
  place in the log (compare-and-set), so of two fusers claiming at once exactly one wins, and a claim made on old
  information (a beat slipped in before it) loses. Retained too: a fuser that joins between a claim and the
  winner's first beat (the winner paused in between) must name that claim's state in a claim of its own;
* ``release (holder, session)``: a clean stop (retained), or the holder's last will (the broker publishes it when the
  connection dies, so a standby takes over at once when the holder is killed). The will is not retained: every
  fuser has one, and a standby's must not stand for the state a newcomer reads (the holder's last beat stays, and a
  claim naming that beat is valid once its holder has released).

**Safety.** The holder publishes a pose only while ``now < s + lease_s``, ``s`` being the time it *sent* its last
beat that came back valid; :meth:`Lease.may_publish` is asked immediately before each publish. A standby claims
only after ``takeover_s`` > ``lease_s`` without a valid beat since it *received* the last one, and its claim names
that beat. A beat is sent before anyone receives it, so by the time the claim wins the old holder has stopped by
its own clock (which need only run at the same rate, not show the same time). This holds for a paused process (it
resumes with an expired lease and learns it lost before its next beat could count) and for a partition (the holder
cut off stops on its own; the others take over after ``takeover_s``).

What it cannot stop: poses already handed to the operating system before a pause or a partition, delivered late by
TCP (at most ``lease_s`` of them, 0.2 s; pose v1 has no field a rover could fence them with). And a fuser that joins
reads the retained entry as the state; in the rare case it is not the state (a beat the old holder sent just after
losing, a claim that lost: each overwritten by the holder's next beat within ``beat_s``), the newcomer takes the
live beats as the state instead (:attr:`Lease.synced` is False until two in a row come from one holder) and claims
on the retained entry alone only when no beat at all arrived for ``takeover_s`` after it joined. Only the holder's
release frees the lease, for a newcomer too. What remains: a newcomer that joins within that ``beat_s`` window while
the holder is paused for ``takeover_s`` may claim on the wrong state; the holder, resuming, could then publish
beside it.

**Liveness.** Killed: its last will arrives at once and a standby claims (a few milliseconds). Paused, frozen or
cut off: ``takeover_s`` plus one round trip. A fuser that (re)connects starts as a standby.
"""

from __future__ import annotations

import math
import secrets
from dataclasses import dataclass, field
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from edge.messages import TOPIC_PREFIX, RoverId

LEASE_TOPIC = f"{TOPIC_PREFIX}/fuser/lease"
LEASE_QOS = 1

Kind = Literal["beat", "claim", "release"]
State = tuple[str | None, str | None, int]  # (holder, session, n); n == -1: free
FREE: State = (None, None, -1)  # nobody has held it (released: the last holder and session, n == -1)


class LeaseMessage(BaseModel):
    """One entry of the lease log on ``ips/v1/fuser/lease`` (QoS 1, retained: the newest entry is the state)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    v: Literal[1] = 1
    kind: Kind
    fuser: RoverId
    session: str = Field(pattern=r"^[0-9a-f]{8,32}$")
    n: int = Field(ge=-1, le=999_999_999)
    after: tuple[str | None, str | None, int] | None = None  # a claim's (holder, session, n) it replaces
    t: float = Field(ge=0.0, lt=1e10)  # the sender's wall clock, for people reading the topic


def new_session() -> str:
    return secrets.token_hex(4)


@dataclass(frozen=True)
class LeaseSettings:
    beat_s: float = 0.05
    lease_s: float = 0.20  # the holder's own validity after a beat it sent
    takeover_s: float = 0.30  # a standby's patience since the last valid beat it received
    retry_s: float = 0.05  # after a claim that lost, before the next

    def __post_init__(self) -> None:
        if not 0 < self.beat_s < self.lease_s < self.takeover_s:
            raise ValueError("lease timing must satisfy 0 < beat_s < lease_s < takeover_s")


@dataclass
class Lease:
    """One fuser's view of the lease. Feed it the log (:meth:`apply`) and the clock (:meth:`due`); ask it before
    every publish (:meth:`may_publish`). Times are ``time.monotonic()`` seconds; ``wall`` only labels messages."""

    me: str
    session: str = field(default_factory=new_session)
    settings: LeaseSettings = field(default_factory=LeaseSettings)
    state: State = FREE
    synced: bool = False  # a live entry (not only the retained one) has been applied since joining
    claims_won: int = 0
    _joined_s: float = 0.0
    _last_valid_s: float = -math.inf  # when this fuser last received a valid beat or claim
    _valid_until_s: float = -math.inf  # this fuser's own lease (holder only)
    _sent: dict[int, float] = field(default_factory=dict)  # n of own beats and claims -> send time
    _claim_pending: bool = False
    _next_claim_s: float = 0.0
    _next_beat_s: float = 0.0
    _my_n: int = 0
    transitions: list[tuple[float, str]] = field(default_factory=list)

    # -- the log ------------------------------------------------------------------------------------------------
    def join(self, now_s: float, session: str | None = None) -> None:
        """(Re)connected (with a new ``session``): forget the state, become a standby, wait for the log."""
        was = self.is_holder
        self.session = session or new_session()
        self.state, self.synced = FREE, False
        self._joined_s = now_s
        self._last_valid_s = -math.inf
        self._valid_until_s = -math.inf
        self._sent.clear()
        self._claim_pending = False
        if was:
            self.transitions.append((now_s, "standby"))

    def apply(self, m: LeaseMessage, now_s: float, retained: bool = False) -> bool:
        """Apply the next entry of the log (``retained``: the broker's stored entry, sent on subscribing)."""
        holder, session, n = self.state
        valid = False
        if retained:  # the state as the log left it, to be confirmed by the live entries that follow
            self._set((m.fuser, m.session, -1 if m.kind == "release" else m.n), now_s)
            return True
        follows = False  # this entry continues the state this fuser holds (a beat of the same holder and session)
        if m.kind == "beat":
            # a live beat while not yet synced is the holder's word: the retained entry was stale. But a lone beat may
            # be a loser's last (sent before it learned it lost): synced only once two in a row come from one holder
            follows = (m.fuser, m.session) == (holder, session) and m.n > n >= 0
            valid = follows or not self.synced
            if valid:
                self._set((m.fuser, m.session, m.n), now_s)
        elif m.kind == "claim":
            # valid on the state it names; or on the same holder's session when one side has seen it released
            # (its last will is not retained: a fuser that joined after it names the holder's last beat, and one
            # that joined before it, but after the release, holds that beat as the state)
            named = tuple(m.after) if m.after is not None else None
            if named == self.state or (
                named is not None and holder is not None and named[:2] == (holder, session) and -1 in (n, named[2])
            ):
                self._set((m.fuser, m.session, m.n), now_s)
                valid = True
                if m.fuser == self.me:
                    self.claims_won += 1
            if m.fuser == self.me and m.session == self.session:
                self._claim_pending = False
                self._next_claim_s = now_s + self.settings.retry_s
        elif m.kind == "release" and (m.fuser, m.session) == (holder, session) and n >= 0:
            # only the holder's release frees the lease, synced or not: any fuser's last will arrives when it dies
            self._set((holder, session, -1), now_s)
            valid = True
        if valid and (m.kind != "beat" or follows or self.synced):
            self.synced = True
            if m.fuser == self.me and m.session == self.session and self.is_holder:
                sent = self._sent.pop(m.n, None)
                if sent is not None:
                    self._valid_until_s = max(self._valid_until_s, sent + self.settings.lease_s)
        return valid

    def _set(self, state: State, now_s: float) -> None:
        was = self.is_holder
        self.state = state
        holder, _, n = state
        self._last_valid_s = now_s if holder is not None and n >= 0 else -math.inf
        if not self.is_holder:
            self._valid_until_s = -math.inf
        if self.is_holder != was:
            self.transitions.append((now_s, "active" if self.is_holder else "standby"))

    # -- decisions ----------------------------------------------------------------------------------------------
    @property
    def is_holder(self) -> bool:
        holder, session, n = self.state
        return holder == self.me and session == self.session and n >= 0

    @property
    def holder(self) -> str | None:
        holder, _, n = self.state
        return holder if n >= 0 else None

    def may_publish(self, now_s: float) -> bool:
        """Ask immediately before each publish: the holder, within its own lease."""
        return self.is_holder and now_s < self._valid_until_s

    def due(self, now_s: float, wall_s: float) -> LeaseMessage | None:
        """The message to publish now, if any: the holder's beat, or a standby's claim."""
        s = self.settings
        if self.is_holder:
            if now_s < self._next_beat_s:
                return None
            self._next_beat_s = now_s + s.beat_s
            self._my_n = max(self._my_n, self.state[2]) + 1
            return self._sending(
                LeaseMessage(kind="beat", fuser=self.me, session=self.session, n=self._my_n, t=wall_s), now_s
            )
        if self._claim_pending or now_s < self._next_claim_s or now_s - self._joined_s < s.takeover_s:
            return None
        free = self.state[0] is None or self.state[2] == -1
        if not free and now_s - self._last_valid_s < s.takeover_s:
            return None
        self._my_n = 0
        self._claim_pending = True
        self._next_claim_s = now_s + s.takeover_s  # if its echo never comes (a partition), try again later
        return self._sending(
            LeaseMessage(kind="claim", fuser=self.me, session=self.session, n=0, after=self.state, t=wall_s), now_s
        )

    def _sending(self, m: LeaseMessage, now_s: float) -> LeaseMessage:
        """Note when ``m`` is sent (no later than the caller hands it to the broker: the lease it earns counts from
        here, on the safe side)."""
        self._sent[m.n] = now_s
        if len(self._sent) > 64:
            for key in sorted(self._sent)[:-32]:
                del self._sent[key]
        return m

    def will(self) -> LeaseMessage:
        """The release the broker publishes for this session when its connection dies (set before connecting)."""
        return LeaseMessage(kind="release", fuser=self.me, session=self.session, n=-1, t=0.0)

    def release(self, wall_s: float) -> LeaseMessage | None:
        """A clean stop's release, when this fuser holds the lease."""
        if not self.is_holder:
            return None
        return LeaseMessage(kind="release", fuser=self.me, session=self.session, n=-1, t=wall_s)
