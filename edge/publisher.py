"""Publishing to MQTT: poses at QoS 0 on one topic per rover, the retained edge status with its last will.

Nothing stale is ever sent. Poses are published only while connected: while disconnected they are dropped and
counted, never queued (paho queues nothing for QoS 0 without a socket, and its outgoing packet buffer is cleared
on reconnect). Status is kept as "the latest" and re-published on every (re)connect. Reconnects run with
exponential backoff on paho's network thread, so the tracker never waits for the network.

With ``hold_poses``, every (re)connection also holds the poses back (not sent, counted in ``poses_held``) until the
:class:`ConnectionHold` handed to ``on_connected`` for that connection is released: the appliance releases it once
its retained ``stop`` for the connection is acknowledged (:class:`edge.commands.StopAtStart`), so a rover that
reconnects to a broker which brought back an older formation gets no fresh pose to drive it on.

The formation command lives in :mod:`edge.commands`, the client set-up in :mod:`edge.mqttclient`; their names
below are kept importable from here.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import paho.mqtt.client as mqtt

from edge.config import BrokerTarget
from edge.errors import BrokerError
from edge.messages import StatusV1, dumps, edge_status_topic, pose_topic
from edge.mqttclient import TlsFiles, connect_host, make_client

log = logging.getLogger("edge.publisher")

Tap = Callable[[str, bytes, bool], None]
"""Called with (topic, payload, retain) for every message handed to the broker connection (the recording)."""

STATUS_QOS = 1


@dataclass
class PublisherStats:
    """Counters for /metrics; written by the publishing thread and paho's network thread."""

    poses_sent: int = 0
    poses_dropped: int = 0
    poses_held: int = 0  # not sent: the connection's stop was not acknowledged yet (hold_poses)
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


class ConnectionHold:
    """One broker connection of an :class:`MqttPublisher` with ``hold_poses``: no pose goes out on it until
    :meth:`release` (any thread; releasing a connection that was replaced since changes nothing)."""

    def __init__(self, publisher: MqttPublisher, number: int) -> None:
        self._publisher = publisher
        self.number = number  # 1 for the first connection, +1 for each reconnection

    @property
    def current(self) -> bool:
        """This connection is still the publisher's, and up."""
        return self._publisher._connection == self.number and self._publisher.connected

    def release(self) -> None:
        self._publisher._release(self.number)


class MqttPublisher:
    """paho-mqtt v2 publisher with last will, status refresh on reconnect and drop-not-queue for poses.

    ``on_connected(hold)`` is called on paho's network thread after each successful CONNACK, with that connection's
    :class:`ConnectionHold`; with ``hold_poses`` the poses wait for its release."""

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
        on_connected: Callable[[ConnectionHold], None] | None = None,
        hold_poses: bool = False,
    ) -> None:
        self.target = target
        self.edge_id = edge_id
        self.rovers = tuple(rovers)
        self.keepalive_s = keepalive_s
        self.tap = tap
        self.on_connected = on_connected
        self.hold_poses = hold_poses
        # Connections are numbered; poses go out only while the current one is released. The lock makes a pose's
        # check and its hand-over to paho one step, so no pose slips onto a connection that has just been made.
        self._hold_lock = threading.Condition()
        self._connection = 0
        self._released = 0
        self._held_since_mono = 0.0
        self._held_at_connect = 0
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
        with self._hold_lock:  # before the connection counts as up: no pose goes out on it unheld
            self._connection += 1
            hold = ConnectionHold(self, self._connection)
            self._held_since_mono = time.monotonic()
            self._held_at_connect = self.stats.poses_held
        self._disconnected.clear()
        self._connected.set()
        self._first_connack.set()
        held = ", poses held until the edge's retained stop is acknowledged" if self.hold_poses else ""
        log.info("connected to broker %s%s", self.target.display(), held)
        status = self._latest_status
        if status is not None:
            self._send_status(status)
        if self.on_connected is not None:
            self.on_connected(hold)

    def _release(self, number: int) -> None:
        with self._hold_lock:
            if number != self._connection or self._released == number:
                return  # a connection replaced since (the newer one has its own stop coming), or released already
            self._released = number
            self._hold_lock.notify_all()
            held = self.stats.poses_held - self._held_at_connect
            waited_s = time.monotonic() - self._held_since_mono
        if self.hold_poses:
            log.info("poses resume: the retained stop is acknowledged (%d held over %.2f s)", held, waited_s)

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

    def wait_poses_released(self, timeout_s: float) -> bool:
        """Wait until connected with the connection's poses released (``hold_poses``: its stop acknowledged);
        False on timeout."""
        if not self.hold_poses:
            return self._connected.wait(timeout_s)
        with self._hold_lock:
            return self._hold_lock.wait_for(lambda: self._released == self._connection and self.connected, timeout_s)

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
        """Hand a pose to the broker connection: False (counted) while disconnected, or held (``hold_poses``)."""
        topic = self._pose_topics.get(rover_id) or pose_topic(rover_id)
        with self._hold_lock:
            held = self.hold_poses and self._released != self._connection and self.connected
            sent = not held and self.publish(topic, payload)
        if sent:
            self.stats.poses_sent += 1
            return True
        if held:
            self.stats.poses_held += 1
            return False
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
