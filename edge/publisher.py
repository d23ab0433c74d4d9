"""Publishing to MQTT: poses at QoS 0 on one topic per rover, the retained edge status with its last will.

Nothing stale is ever sent. Poses are published only while connected: while disconnected they are dropped and
counted, never queued (paho queues nothing for QoS 0 without a socket, and its outgoing packet buffer is cleared
on reconnect). Status is kept as "the latest" and re-published on every (re)connect. Reconnects run with
exponential backoff on paho's network thread, so the tracker never waits for the network.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import ssl
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import paho.mqtt.client as mqtt

from edge.config import BrokerTarget
from edge.errors import BrokerError, ConfigError, describe_validation
from edge.messages import (
    FORMATION_TOPIC,
    FormationKind,
    FormationV1,
    StatusV1,
    dumps,
    edge_status_topic,
    parse_formation,
    pose_topic,
)

log = logging.getLogger("edge.publisher")

Tap = Callable[[str, bytes, bool], None]
"""Called with (topic, payload, retain) for every message handed to the broker connection (the recording)."""

STATUS_QOS = 1
FORMATION_QOS = 1
LINE_SPACING_CM = 60.0  # a line's distance between neighbours when the command names none
TRIANGLE_SIDE_CM = 100.0  # a triangle's side when the command names none


@dataclass
class PublisherStats:
    """Counters for /metrics; written by the publishing thread and paho's network thread."""

    poses_sent: int = 0
    poses_dropped: int = 0
    statuses_sent: int = 0
    connects: int = 0
    disconnects: int = 0
    last_error: str = ""
    connected_since_mono: float | None = None
    dropped_by_rover: dict[str, int] = field(default_factory=dict)


class Publisher(Protocol):
    """Where the runtime sends what it measured."""

    stats: PublisherStats

    @property
    def connected(self) -> bool: ...

    def start(self) -> None: ...

    def publish_pose(self, rover_id: str, payload: bytes) -> bool: ...

    def publish_status(self, status: StatusV1) -> bool: ...

    def publish(self, topic: str, payload: bytes, *, qos: int = 0, retain: bool = False) -> bool: ...

    def stop(self, final_status: StatusV1 | None = None, timeout_s: float = 3.0) -> None: ...


def offline_status(edge_id: str, rovers: Sequence[str], t: float | None = None) -> StatusV1:
    """The status the last will (and a clean shutdown) leaves retained."""
    return StatusV1(
        v=1,
        edge=edge_id,
        state="offline",
        camera="stopped",
        fps=0.0,
        rovers=[],
        missing=list(rovers),
        t=round(time.time() if t is None else t, 3),
    )


@dataclass(frozen=True)
class TlsFiles:
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None

    def check(self) -> None:
        for key, path in (("ca_file", self.ca_file), ("cert_file", self.cert_file), ("key_file", self.key_file)):
            if path is not None and not path.is_file():
                raise ConfigError(f"broker.{key}: {path} not found")
        if (self.cert_file is None) != (self.key_file is None):
            raise ConfigError("broker.cert_file and broker.key_file go together: give both or neither")


def make_client(
    target: BrokerTarget,
    client_id: str,
    *,
    tls: TlsFiles | None = None,
    reconnect_min_s: float = 0.25,
    reconnect_max_s: float = 2.0,
) -> mqtt.Client:
    """A paho v2 client (MQTT 3.1.1, clean session) set up for ``target``, not yet connected."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True)
    if target.username is not None:
        client.username_pw_set(target.username, target.password)
    if target.tls:
        files = tls or TlsFiles()
        files.check()
        client.tls_set(
            ca_certs=str(files.ca_file) if files.ca_file else None,
            certfile=str(files.cert_file) if files.cert_file else None,
            keyfile=str(files.key_file) if files.key_file else None,
            cert_reqs=ssl.CERT_REQUIRED,
        )
    client.reconnect_delay_set(min_delay=reconnect_min_s, max_delay=reconnect_max_s)  # type: ignore[arg-type]
    client.on_socket_open = _no_delay
    return client


def _no_delay(client: mqtt.Client, userdata: Any, sock: Any) -> None:
    # paho leaves Nagle's algorithm on: the 2nd and 3rd pose of a frame would wait for the broker's delayed ACK
    # (up to 40 ms on Linux). Poses are small and latency-bound, so send each segment at once.
    with contextlib.suppress(OSError, AttributeError):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def connect_host(target: BrokerTarget) -> str:
    # The embedded broker listens on every interface; this process reaches it over loopback.
    return "127.0.0.1" if target.embedded and target.host in ("0.0.0.0", "::", "") else target.host


class MqttPublisher:
    """paho-mqtt v2 publisher with last will, status refresh on reconnect and drop-not-queue for poses."""

    def __init__(
        self,
        target: BrokerTarget,
        *,
        edge_id: str,
        rovers: Sequence[str],
        client_id: str | None = None,
        keepalive_s: int = 10,
        reconnect_min_s: float = 0.25,
        reconnect_max_s: float = 2.0,
        tls: TlsFiles | None = None,
        tap: Tap | None = None,
        on_connected: Callable[[], None] | None = None,
    ) -> None:
        self.target = target
        self.edge_id = edge_id
        self.rovers = tuple(rovers)
        self.keepalive_s = keepalive_s
        self.tap = tap
        self.on_connected = on_connected
        self.stats = PublisherStats()
        self._status_topic = edge_status_topic(edge_id)
        self._pose_topics = {r: pose_topic(r) for r in self.rovers}
        self._latest_status: StatusV1 | None = None
        self._connected = threading.Event()
        self._disconnected = threading.Event()  # the complement of _connected, to wait on
        self._first_connack = threading.Event()
        self._first_refusal: str | None = None
        self._last_logged_error = ""
        self._stopping = False
        self._client = make_client(
            target,
            client_id or f"edge-ips-{edge_id}",
            tls=tls,
            reconnect_min_s=reconnect_min_s,
            reconnect_max_s=reconnect_max_s,
        )
        self._set_will()
        self._client.on_connect = self._on_connect
        self._client.on_disconnect = self._on_disconnect

    # -- paho callbacks (network thread) ------------------------------------------------------------------------
    def _set_will(self) -> None:
        will = dumps(offline_status(self.edge_id, self.rovers))
        self._client.will_set(self._status_topic, will, qos=STATUS_QOS, retain=True)

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason_code: Any, props: Any) -> None:
        if reason_code.is_failure:
            message = f"broker {self.target.display()} refused the connection: {reason_code}"
            self.stats.last_error = message
            if not self._first_connack.is_set():
                self._first_refusal = message
            if message != self._last_logged_error:
                log.error("%s", message)
                self._last_logged_error = message
            self._first_connack.set()
            return
        self.stats.connects += 1
        self.stats.connected_since_mono = time.monotonic()
        self._last_logged_error = ""
        self._disconnected.clear()
        self._connected.set()
        self._first_connack.set()
        log.info("connected to broker %s", self.target.display())
        status = self._latest_status
        if status is not None:
            self._send_status(status)
        if self.on_connected is not None:
            self.on_connected()

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason_code: Any, props: Any) -> None:
        was_connected = self._connected.is_set()
        self._connected.clear()
        self._disconnected.set()
        self.stats.connected_since_mono = None
        if was_connected and not self._stopping:
            self.stats.disconnects += 1
            self.stats.last_error = f"disconnected: {reason_code}"
            log.warning("lost broker %s (%s); reconnecting with backoff", self.target.display(), reason_code)
        self._set_will()  # the will's t then says when this connection was lost

    # -- the Publisher protocol ---------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def wait_disconnected(self, timeout_s: float) -> bool:
        """Wait until the connection is known to be lost (paho saw it go); False on timeout."""
        return self._disconnected.wait(timeout_s)

    def start(self) -> None:
        """Begin connecting in the background (paho's network thread retries with backoff)."""
        host = connect_host(self.target)
        try:
            self._client.connect_async(host, self.target.port, keepalive=self.keepalive_s)
        except ValueError as exc:
            raise BrokerError(f"broker {self.target.display()}: {exc}") from exc
        self._client.loop_start()

    def wait_connected(self, timeout_s: float) -> bool:
        """Wait until connected; raises :class:`BrokerError` if the broker refused the first connection attempt."""
        deadline = time.monotonic() + timeout_s
        self._first_connack.wait(timeout_s)
        if self._first_refusal is not None and not self.connected:
            raise BrokerError(self._first_refusal + " (check broker.username and broker.password)")
        return self._connected.wait(max(0.0, deadline - time.monotonic()))

    def publish(self, topic: str, payload: bytes, *, qos: int = 0, retain: bool = False) -> bool:
        if not self._connected.is_set():
            return False
        info = self._client.publish(topic, payload, qos=qos, retain=retain)
        if info.rc != mqtt.MQTT_ERR_SUCCESS:
            return False
        if self.tap is not None:
            self.tap(topic, payload, retain)
        return True

    def publish_pose(self, rover_id: str, payload: bytes) -> bool:
        topic = self._pose_topics.get(rover_id) or pose_topic(rover_id)
        if self.publish(topic, payload):
            self.stats.poses_sent += 1
            return True
        self.stats.poses_dropped += 1
        self.stats.dropped_by_rover[rover_id] = self.stats.dropped_by_rover.get(rover_id, 0) + 1
        return False

    def _send_status(self, status: StatusV1) -> bool:
        sent = self.publish(self._status_topic, dumps(status), qos=STATUS_QOS, retain=True)
        if sent:
            self.stats.statuses_sent += 1
        return sent

    def publish_status(self, status: StatusV1) -> bool:
        """Publish now if connected; either way it is the status sent on the next (re)connect."""
        self._latest_status = status
        return self._send_status(status)

    def stop(self, final_status: StatusV1 | None = None, timeout_s: float = 3.0) -> None:
        """Publish ``final_status`` (offline) and wait for the broker's ack, then disconnect cleanly."""
        self._stopping = True
        if final_status is not None and self.connected:
            info = self._client.publish(self._status_topic, dumps(final_status), qos=STATUS_QOS, retain=True)
            if self.tap is not None and info.rc == mqtt.MQTT_ERR_SUCCESS:
                self.tap(self._status_topic, dumps(final_status), True)
            try:
                info.wait_for_publish(timeout_s)
            except (RuntimeError, ValueError):
                log.warning("final status not acknowledged by the broker")
            if not info.is_published():
                log.warning("final status not acknowledged within %.1f s; the last will covers it", timeout_s)
        self._client.disconnect()
        self._client.loop_stop()
        self._connected.clear()


# -- in memory, for tests and the simulator ----------------------------------------------------------------------
@dataclass(frozen=True)
class Published:
    topic: str
    payload: bytes
    qos: int
    retain: bool
    t_mono_s: float


class MemoryPublisher:
    """Keeps every message in :attr:`messages`; ``connected`` can be switched off to test dropping.
    :meth:`wait_until` waits for what has been published (or dropped) to satisfy a condition."""

    def __init__(self, *, tap: Tap | None = None) -> None:
        self.stats = PublisherStats()
        self.messages: list[Published] = []
        self.tap = tap
        self.is_connected = True
        self._lock = threading.Condition(threading.RLock())
        self.edge_status_topic: str | None = None

    @property
    def connected(self) -> bool:
        return self.is_connected

    def start(self) -> None:
        self.stats.connects += 1

    def publish(self, topic: str, payload: bytes, *, qos: int = 0, retain: bool = False) -> bool:
        if not self.is_connected:
            return False
        with self._lock:
            self.messages.append(Published(topic, payload, qos, retain, time.monotonic()))
            self._lock.notify_all()
        if self.tap is not None:
            self.tap(topic, payload, retain)
        return True

    def publish_pose(self, rover_id: str, payload: bytes) -> bool:
        if self.publish(pose_topic(rover_id), payload):
            self.stats.poses_sent += 1
            return True
        with self._lock:
            self.stats.poses_dropped += 1
            self.stats.dropped_by_rover[rover_id] = self.stats.dropped_by_rover.get(rover_id, 0) + 1
            self._lock.notify_all()
        return False

    def publish_status(self, status: StatusV1) -> bool:
        sent = self.publish(edge_status_topic(status.edge), dumps(status), qos=STATUS_QOS, retain=True)
        self.stats.statuses_sent += int(sent)
        return sent

    def stop(self, final_status: StatusV1 | None = None, timeout_s: float = 3.0) -> None:
        if final_status is not None:
            self.publish_status(final_status)

    def on(self, topic: str) -> list[bytes]:
        """Payloads published on ``topic``, in order."""
        with self._lock:
            return [m.payload for m in self.messages if m.topic == topic]

    def wait_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Block until ``condition()`` holds (checked after each message published or pose dropped; it may call
        :meth:`on`); False when ``timeout_s`` passed first."""
        with self._lock:
            return self._lock.wait_for(condition, timeout_s)


# -- one-shot publishing: the formation command ------------------------------------------------------------------
def _connect_blocking(client: mqtt.Client, target: BrokerTarget, timeout_s: float) -> None:
    done = threading.Event()
    result: list[str] = []

    def on_connect(c: mqtt.Client, u: Any, flags: Any, reason_code: Any, props: Any) -> None:
        result.append("" if not reason_code.is_failure else str(reason_code))
        done.set()

    client.on_connect = on_connect
    try:
        client.connect(connect_host(target), target.port, keepalive=10)
    except (OSError, ssl.SSLError) as exc:
        raise BrokerError(f"cannot reach broker {target.display()}: {exc}") from exc
    client.loop_start()
    if not done.wait(timeout_s):
        client.loop_stop()
        raise BrokerError(f"broker {target.display()} did not answer within {timeout_s:g} s")
    if result[0]:
        client.loop_stop()
        raise BrokerError(f"broker {target.display()} refused the connection: {result[0]}")


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
    from pydantic import ValidationError

    from edge.errors import MessageError

    ids = [i.strip() for i in ids]
    unknown = [i for i in ids if known_ids is not None and i not in known_ids]
    if unknown:
        raise MessageError(f"formation: ids: not configured rovers: {', '.join(unknown)}")
    twice = sorted({i for i in ids if ids.count(i) > 1})
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


def send_formation(
    target: BrokerTarget,
    make: Callable[[int], FormationV1],
    *,
    client_id: str = "",
    tls: TlsFiles | None = None,
    timeout_s: float = 5.0,
    retained_wait_s: float = 0.5,
) -> FormationV1:
    """Publish a retained formation whose ``seq`` follows the one currently retained (1 if none).

    ``make(seq)`` builds the message. Returns what was published once the broker acknowledged it.
    """
    client = make_client(target, client_id, tls=tls)
    current: list[FormationV1] = []
    got = threading.Event()

    def on_message(c: mqtt.Client, u: Any, message: mqtt.MQTTMessage) -> None:
        try:
            current.append(parse_formation(bytes(message.payload)))
        except Exception as exc:  # a foreign retained payload: start a new sequence, but say so
            log.warning("ignoring the retained formation on the broker: %s", exc)
        got.set()

    client.on_message = on_message
    _connect_blocking(client, target, timeout_s)
    try:
        client.subscribe(FORMATION_TOPIC, qos=FORMATION_QOS)
        got.wait(retained_wait_s)  # a retained message arrives right after the subscription, if there is one
        client.unsubscribe(FORMATION_TOPIC)
        seq = (current[-1].seq + 1) if current else 1
        message = make(seq)
        info = client.publish(FORMATION_TOPIC, dumps(message), qos=FORMATION_QOS, retain=True)
        info.wait_for_publish(timeout_s)
        if not info.is_published():
            raise BrokerError(f"broker {target.display()} did not acknowledge the formation within {timeout_s:g} s")
        return message
    finally:
        client.disconnect()
        client.loop_stop()
