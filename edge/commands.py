"""The formation command: building one, the seq after the retained one, sending it (the dashboard and
``edge-ips formation``), and the appliance's own ``stop`` when it starts.

The contract's rules (``shared/schema/README.md``, "Commands"): rovers compare whole commands and always obey
``stop``, so a writer only has to keep ``seq`` moving (:func:`edge.messages.next_seq`: 999999999 is followed by 1) and
must never fail because of what is retained (a hostile seq, a foreign payload, a cleared message).
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import paho.mqtt.client as mqtt
from pydantic import ValidationError

from edge.config import BrokerTarget, EdgeConfig
from edge.errors import BrokerError, EdgeIpsError, MessageError, describe_validation
from edge.messages import FORMATION_TOPIC, FormationKind, FormationV1, dumps, next_seq, parse_formation, repeated_ids
from edge.mqttclient import TlsFiles, connect_blocking, make_client

log = logging.getLogger("edge.commands")

FORMATION_QOS = 1
LINE_SPACING_CM = 60.0  # a line's distance between neighbours when the command names none
TRIANGLE_SIDE_CM = 100.0  # a triangle's side when the command names none
RETAINED_WAIT_S = 0.5  # how long a retained formation may take to arrive after subscribing (MQTT has no "none")
RETRY_MIN_S = 0.5  # a stop at (re)connection the broker did not take is tried again after this...
RETRY_MAX_S = 5.0  # ... doubling up to this, while the poses stay held


def build_formation(
    kind: FormationKind,
    ids: Sequence[str],
    *,
    seq: int,
    spacing_cm: float | None = None,
    side_cm: float | None = None,
    x_cm: float | None = None,
    y_cm: float | None = None,
    theta_rad: float | None = None,
    known_ids: Sequence[str] | None = None,
) -> FormationV1:
    """A validated formation message (raises :class:`MessageError` naming the bad field): what a command may say,
    for ``edge-ips formation``, the dashboard and the simulator alike.

    Ids are taken without surrounding spaces and, when ``known_ids`` is given, must be among them. A line's
    ``spacing_cm`` defaults to :data:`LINE_SPACING_CM`, a triangle's ``side_cm`` to :data:`TRIANGLE_SIDE_CM`; other
    kinds carry neither. Beyond the contract: every rover is named once, a formation other than ``stop`` names at
    least one rover, and a triangle at least three (the firmware would make a 2-gon of two)."""
    ids = [i.strip() for i in ids]
    unknown = [i for i in ids if known_ids is not None and i not in known_ids]
    if unknown:
        raise MessageError(f"formation: ids: not configured rovers: {', '.join(unknown)}")
    twice = repeated_ids(ids)
    if twice:
        raise MessageError(f"formation: ids: {', '.join(twice)} named more than once")
    if kind != "stop" and not ids:
        raise MessageError(f"formation: ids: a {kind} needs at least one rover")
    if kind == "triangle" and len(ids) < 3:
        raise MessageError(f"formation: ids: a triangle needs at least three rovers, got {len(ids)}")
    spacing_cm = (LINE_SPACING_CM if spacing_cm is None else spacing_cm) if kind == "line" else None
    side_cm = (TRIANGLE_SIDE_CM if side_cm is None else side_cm) if kind == "triangle" else None
    try:
        return FormationV1(
            v=1,
            seq=seq,
            kind=kind,
            ids=ids,
            spacing=spacing_cm,
            side=side_cm,
            x=x_cm,
            y=y_cm,
            theta=theta_rad,
        )
    except ValidationError as exc:
        raise MessageError(f"formation: {describe_validation(exc)}") from exc


def read_retained(payload: bytes) -> FormationV1 | None:
    """The retained formation a writer continues from: None when it is cleared (empty) or breaks the contract (a
    foreign payload is said in the log and otherwise ignored: the next seq is 1)."""
    if not payload:
        return None
    try:
        return parse_formation(payload)
    except MessageError as exc:
        log.warning("ignoring the retained formation on the broker: %s", exc)
        return None


def send_formation(
    target: BrokerTarget,
    make: Callable[[int], FormationV1],
    *,
    client_id: str = "",
    tls: TlsFiles | None = None,
    timeout_s: float = 5.0,
    retained_wait_s: float = RETAINED_WAIT_S,
) -> FormationV1:
    """Publish a retained formation whose ``seq`` follows the one currently retained (:func:`next_seq`: 1 if none
    or if it breaks the contract, and 999999999 is followed by 1), on a connection of its own.

    ``make(seq)`` builds the message. Returns what was published once the broker acknowledged it. Rovers compare
    whole commands, so two writers at once may publish the same seq: both are applied, in the broker's order.
    """
    client = make_client(target, client_id, tls=tls)
    connect_blocking(client, target, timeout_s)
    try:
        return send_formation_on(client, target, make, timeout_s=timeout_s, retained_wait_s=retained_wait_s)
    finally:
        client.disconnect()
        client.loop_stop()


def send_formation_on(
    client: mqtt.Client,
    target: BrokerTarget,
    make: Callable[[int], FormationV1],
    *,
    timeout_s: float = 5.0,
    retained_wait_s: float = RETAINED_WAIT_S,
) -> FormationV1:
    """:func:`send_formation` on a connection that is up already, its network loop running (``target`` names the
    broker in errors): the fuser's own, where a second connection with its login would take over its session (the
    central broker's client ids are the user names). The formation topic's messages go to this call only while it
    runs (paho's per-topic callback); it blocks, so never call it on the network thread."""
    current: list[FormationV1 | None] = []
    got = threading.Event()

    def on_message(c: mqtt.Client, u: Any, message: mqtt.MQTTMessage) -> None:
        current.append(read_retained(bytes(message.payload)))
        got.set()

    def retained_now(wait_s: float) -> FormationV1 | None:
        """What the broker holds: a retained message arrives right after the subscription, if there is one."""
        current.clear()
        got.clear()
        client.subscribe(FORMATION_TOPIC, qos=FORMATION_QOS)
        got.wait(wait_s)
        client.unsubscribe(FORMATION_TOPIC)
        return current[-1] if current else None

    client.message_callback_add(FORMATION_TOPIC, on_message)
    try:
        retained = retained_now(retained_wait_s)
        seq = next_seq(retained.seq if retained is not None else None)
        message = make(seq)
        info = client.publish(FORMATION_TOPIC, dumps(message), qos=FORMATION_QOS, retain=True)
        try:
            info.wait_for_publish(timeout_s)
        except (RuntimeError, ValueError) as exc:  # not connected (any more), paho's queue full
            raise BrokerError(f"broker {target.display()}: the formation was not sent: {exc}") from exc
        if not info.is_published():
            raise BrokerError(f"broker {target.display()} did not acknowledge the formation within {timeout_s:g} s")
        # read it back: an MQTT 3.1.1 broker acknowledges a publish its ACL drops, and a command (a STOP) that
        # silently went nowhere must not look sent
        now = retained_now(timeout_s)
        if now != message and now == retained:
            raise BrokerError(
                f"broker {target.display()} acknowledged the formation but did not take it: this login may not "
                "publish formations there (with several camera boards, command at the central broker)"
            )
        return message
    finally:
        client.message_callback_remove(FORMATION_TOPIC)


def publish_formation(
    config: EdgeConfig,
    kind: FormationKind,
    ids: Sequence[str] | None = None,
    *,
    spacing_cm: float | None = None,
    side_cm: float | None = None,
    x_cm: float | None = None,
    y_cm: float | None = None,
    theta_rad: float | None = None,
) -> FormationV1:
    """``edge-ips formation``: the command checked first (a mistake is said before connecting), then published
    retained on the edge's broker (:func:`edge.broker.clients.select_broker`) with the seq after the one it holds.
    ``ids``: the rovers in formation order (None: the configured ones)."""
    from edge.broker.clients import select_broker

    chosen = list(ids) if ids is not None else [r.id for r in config.rovers]

    def make(seq: int) -> FormationV1:
        return build_formation(
            kind, chosen, seq=seq, spacing_cm=spacing_cm, side_cm=side_cm, x_cm=x_cm, y_cm=y_cm, theta_rad=theta_rad
        )

    make(1)
    return send_formation(
        select_broker(config).target,
        make,
        client_id=f"edge-ips-formation-{config.edge.id}",
        tls=TlsFiles.of(config.broker),
    )


FormationSender = Callable[[Callable[[int], FormationV1]], FormationV1]
"""Publishes ``make(seq)`` retained after the retained formation (:func:`send_formation`'s contract): raises
:class:`EdgeIpsError` when the broker did not take it."""


class HeldConnection(Protocol):
    """A broker connection whose poses wait for its stop: :class:`edge.publisher.ConnectionHold` (the edge's
    publisher), the fuser's connection (:class:`edge.fusion.service.FuserService`)."""

    @property
    def number(self) -> int:
        """1 for the first connection, +1 for each reconnection."""
        ...

    @property
    def current(self) -> bool:
        """This connection is still its owner's, and up."""
        ...

    def release(self) -> None:
        """Let the poses out on this connection (any thread; a connection replaced since changes nothing)."""
        ...


class StopAtStart:
    """The retained ``stop`` whenever the edge's publisher or a fuser (re)connects, so that after an edge restart,
    crash or power cut, and after a broker restart, every rover halts until someone commands again.

    A broker that comes back may hold an older formation than the last command: Mosquitto saves its retained
    messages on a clean exit or every ``autosave_interval`` (30 min), so after a crash or power cut it brings back
    whatever it saved last (a ``line`` that the ``stop`` after it had replaced), and a rover that reconnects
    forgets its formation and applies that. The edge (or the fuser) cannot tell such a replay from a command it
    missed, so it halts the fleet; and until its stop is acknowledged, the connection's :class:`HeldConnection`
    keeps the poses back, so a rover that reconnected first has no fresh pose to drive the replay on (its safety
    layer halts it ``stale``).

    Sent with :func:`send_formation` (its own short connection, seq after the retained one), or with ``send`` (the
    fuser's: :func:`send_formation_on` its own connection), from :meth:`on_connected`; the hold is released once the
    broker acknowledged the stop. A connection made while a stop is on its way gets one more after it. A failed
    attempt keeps the poses held and is made again every ``retry_min_s``, doubling up to ``retry_max_s``, while the
    connection lasts (and at the next one): releasing them would let the fleet drive on whatever the broker holds,
    while held poses only keep it halted. (A camera board of several, ``retry=False``, publishes no poses and its
    broker takes formations from the central one only: one attempt per connection, logged.)
    :attr:`done` is set once the broker acknowledged the first stop; ``tap(topic, payload, retain)`` is shown each
    (the recording, like everything the edge publishes).
    """

    def __init__(
        self,
        target: BrokerTarget | None = None,
        *,
        client_id: str = "",
        tls: TlsFiles | None = None,
        send: FormationSender | None = None,
        tap: Callable[[str, bytes, bool], None] | None = None,
        retry_min_s: float = RETRY_MIN_S,
        retry_max_s: float = RETRY_MAX_S,
        retry: bool = True,
    ) -> None:
        if send is None:
            if target is None:
                raise TypeError("StopAtStart needs the broker's target or a send function")
            send = functools.partial(send_formation, target, client_id=client_id, tls=tls)
        self.send = send
        self.tap = tap
        self.retry_min_s = retry_min_s
        self.retry_max_s = retry_max_s
        self.retry = retry
        self.done = threading.Event()
        self.attempts = 0  # stops tried, for the log and the tests
        self._lock = threading.Condition()
        self._pending: HeldConnection | None = None  # the newest connection that has not had its stop yet
        self._thread: threading.Thread | None = None

    def on_connected(self, hold: HeldConnection) -> None:
        """Send a stop for this connection, after the one on its way if any (any thread; returns at once)."""
        with self._lock:
            self._pending = hold
            self._lock.notify_all()
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="stop-at-start", daemon=True)
                self._thread.start()

    def _run(self) -> None:
        while True:
            with self._lock:
                hold = self._pending
                if hold is None:
                    self._thread = None
                    return
                self._pending = None
            self._stop_for(hold)

    def _stop_for(self, hold: HeldConnection) -> None:
        """Send until the broker takes the stop, then release the connection's poses; give up on a connection
        that is gone (lost, or replaced by a newer one, which is handled next)."""
        delay_s = self.retry_min_s
        said = ""
        while True:
            error = self._send(hold)
            if error is None:
                hold.release()
                return
            if not self.retry:
                log.warning("the retained stop was not published (%s); trying again at the next connection", error)
                return
            if error != said:  # once per connection and cause, not at every retry
                log.warning(
                    "the retained stop was not published (%s); poses stay held, trying again every %g-%g s",
                    error,
                    self.retry_min_s,
                    self.retry_max_s,
                )
                said = error
            with self._lock:
                if self._lock.wait_for(lambda: self._pending is not None, delay_s) or not hold.current:
                    return
            delay_s = min(2 * delay_s, self.retry_max_s)

    def _send(self, hold: HeldConnection) -> str | None:
        """One attempt: None when the broker took the stop, else why not."""
        when = "at start" if hold.number == 1 else "after the broker connection came back"
        self.attempts += 1
        try:
            sent = self.send(lambda seq: build_formation("stop", [], seq=seq))
        except EdgeIpsError as exc:
            return str(exc)
        if self.tap is not None:
            self.tap(FORMATION_TOPIC, dumps(sent), True)
        self.done.set()
        log.info(
            "published a retained stop (seq %d) %s: every rover halts until someone commands again",
            sent.seq,
            when,
        )
        return None
