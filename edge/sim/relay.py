"""A rover's Wi-Fi hop in the closed loop: a TCP relay between its firmware's MQTT connection and the broker that
hands over each MQTT packet when the rover's :class:`~edge.sim.link.LinkModel` says, on the simulated clock.

::

    HostRover (the firmware, umqtt) <-- TCP --> LinkRelay <-- TCP --> broker (amqtt or Mosquitto)

The relay's thread reads whole MQTT packets from both sides, stamps each with the simulated time it was sent and
asks the connection's link stream when it arrives (or that it never does). The loop calls :meth:`LinkRelay.release`
before each of the rover's control steps: everything due by then is written to the rover (or the broker), and the
relay waits until it has left for the rover's socket, so the firmware's step reads exactly what has arrived by
its time, at its own pace (``link.py`` drains at most 16 messages a step). What the firmware writes (pings, its
status, acknowledgements) crosses the air the same way, upstream.

Two exceptions, both because the simulated clock cannot move while the firmware is blocked inside umqtt: between
the firmware's CONNECT or SUBSCRIBE and the broker's CONNACK or SUBACK every packet passes at once (a handshake takes
a few round trips, milliseconds); and at start-up (``transparent``) the rovers connect and get the formation before
the clock starts.

The association: :class:`Station` stands in for the firmware's station interface (``network.WLAN``) and reports
what the model says, so in a long outage the firmware itself sees Wi-Fi gone, drops its connection and reconnects
when it is back, exactly as on the chip. Packets for a connection the rover has closed are lost; the broker keeps
its end (half-open) until its keepalive runs out or the rover's new connection takes the session over.

The relay keeps no time of its own: ``clock_s`` stamps what it reads, :meth:`LinkRelay.release` hands over what is
due. Between a real broker and rovers running in real time, pass ``time.monotonic`` and call ``release`` from a
timer (every few milliseconds), and set ``transparent`` to False once the rovers are up.
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import math
import selectors
import socket
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from edge.sim.link import LinkModel, Stream

CONNECT, CONNACK, PUBLISH, SUBSCRIBE, SUBACK = 1, 2, 3, 8, 9
_NAMES = {1: "connect", 2: "connack", 3: "publish", 4: "puback", 8: "subscribe", 9: "suback", 12: "ping", 13: "pong"}
_CLOSE = b""  # in a queue: close the socket (the FIN crosses the air in order, like the data before it)


class MalformedPacket(Exception):
    """Bytes that are not MQTT 3.1.1 framing."""


def split_packets(buf: bytearray) -> list[bytes]:
    """Take every complete MQTT packet off the front of ``buf`` (fixed header, remaining length, body)."""
    out: list[bytes] = []
    while len(buf) >= 2:
        length, shift, i = 0, 0, 1
        while True:
            if i >= len(buf):
                return out
            byte = buf[i]
            length |= (byte & 0x7F) << shift
            shift += 7
            i += 1
            if not byte & 0x80:
                break
            if i > 4:
                raise MalformedPacket("remaining length longer than 4 bytes")
        if len(buf) < i + length:
            return out
        out.append(bytes(buf[: i + length]))
        del buf[: i + length]
    return out


def publish_topic_payload(packet: bytes) -> tuple[str, bytes]:
    """(topic, payload) of a PUBLISH packet."""
    i = 1
    while packet[i] & 0x80:
        i += 1
    i += 1
    n = packet[i] << 8 | packet[i + 1]
    topic = packet[i + 2 : i + 2 + n].decode("utf-8", "replace")
    body = i + 2 + n + (2 if packet[0] & 0x06 else 0)
    return topic, packet[body:]


class Station:
    """The firmware's ``network.WLAN`` on a modelled link: associated whenever the model says so (the ESP8266
    reassociates on its own when the access point is back; ``connect`` only asks it to)."""

    def __init__(self, model: LinkModel, clock_s: Callable[[], float]) -> None:
        self._model = model
        self._clock_s = clock_s
        self._active = True

    def active(self, is_active: bool | None = None) -> bool | None:
        if is_active is None:
            return self._active
        self._active = bool(is_active)
        return None

    def connect(self, ssid: str | None = None, key: str | None = None) -> None:
        self._active = True

    def disconnect(self) -> None:
        self._active = False

    def isconnected(self) -> bool:
        return self._active and self._model.associated(self._clock_s())


@dataclass
class RelayLog:
    """What crossed one rover's link: air delays of its poses (broker to rover, head-of-line waits included, s),
    poses that never arrived (their connection went first), and per connection the messages delivered to the rover
    by topic (or packet type)."""

    pose_delays_s: list[float] = field(default_factory=list)
    poses_lost: int = 0
    poses_retransmitted: int = 0
    delivered: list[Counter[str]] = field(default_factory=list)

    @property
    def connections(self) -> int:
        return len(self.delivered)


@dataclass(frozen=True)
class _Queued:
    due_s: float
    packet: bytes  # _CLOSE: close the receiving side
    flow: str


class _Way:
    """One direction of a relayed connection: bytes read from ``source``, whole packets queued for ``target``."""

    def __init__(self, name: str, stream: Stream) -> None:
        self.name = name  # "down": broker -> rover; "up": rover -> broker
        self.stream = stream
        self.buffer = bytearray()
        self.queue: deque[_Queued] = deque()


class _Connection:
    """One TCP connection of the firmware, relayed: its two sockets and two ways."""

    def __init__(self, rover: socket.socket, broker: socket.socket, streams: tuple[Stream, Stream], index: int) -> None:
        self.index = index  # its place in the relay's log
        self.rover: socket.socket | None = rover
        self.broker: socket.socket | None = broker
        self.down = _Way("down", streams[0])
        self.up = _Way("up", streams[1])
        self.awaiting_ack = 0  # CONNECT / SUBSCRIBE sent, CONNACK / SUBACK not back yet
        self.subscribed = False

    def target(self, way: _Way) -> socket.socket | None:
        return self.rover if way is self.down else self.broker

    def way_from(self, side: str) -> _Way:
        return self.up if side == "rover" else self.down

    def close_side(self, side: str) -> socket.socket | None:
        sock = self.rover if side == "rover" else self.broker
        if side == "rover":
            self.rover = None
        else:
            self.broker = None
        return sock

    @property
    def live(self) -> bool:
        """The broker holds a subscription of this connection (poses will come through it)."""
        return self.subscribed and self.broker is not None


class LinkRelay:
    """One rover's Wi-Fi hop (see the module docstring). ``clock_s``: the simulated time, seconds."""

    def __init__(self, broker_host: str, broker_port: int, model: LinkModel, clock_s: Callable[[], float]) -> None:
        self.model = model
        self.log = RelayLog()
        self.transparent = True
        self._broker = (broker_host, broker_port)
        self._clock_s = clock_s
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port: int = self._listener.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ, "listen")
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._connections: list[_Connection] = []
        self._seen: dict[str, bytes] = {}  # topic -> newest payload the broker sent this rover
        self._cond = threading.Condition()
        self._stop = False
        self._counting = True
        self._thread = threading.Thread(target=self._run, name=f"link-relay-{self.port}", daemon=True)

    def start(self) -> LinkRelay:
        self._thread.start()
        return self

    # -- the loop's side -----------------------------------------------------------------------------------------
    def wait_for(self, payloads: Mapping[str, bytes], timeout_s: float) -> bool:
        """Wait until the broker has sent this rover the newest of ``payloads`` (topic -> payload) on every topic;
        False after ``timeout_s`` of real time. True at once when the broker holds no subscription through the
        relay (nothing will come)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while any(c.live for c in self._connections):
                if all(self._seen.get(topic) == payload for topic, payload in payloads.items()):
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def release(self, now_s: float) -> None:
        """Hand over everything due by ``now_s``; returns when the rover's socket has what was written to it."""
        written: list[socket.socket] = []
        with self._cond:
            for c in list(self._connections):
                rover = c.rover
                if self._flush(c, c.down, now_s) and rover is not None:
                    written.append(rover)
                self._flush(c, c.up, now_s)
                self._forget(c)
        for sock in written:
            _wait_sent(sock)

    def finish(self) -> None:
        """The run is over: what is still in flight from here on is not counted as lost."""
        with self._cond:
            self._counting = False

    def close(self) -> None:
        self._stop = True
        self._wake_w.send(b"x")
        self._thread.join(timeout=5.0)
        with self._cond:
            for c in self._connections:
                for sock in (c.rover, c.broker):
                    if sock is not None:
                        sock.close()
            self._connections.clear()
        self._selector.close()
        for sock in (self._listener, self._wake_r, self._wake_w):
            sock.close()

    # -- the relay's thread --------------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop:
            for key, _ in self._selector.select(timeout=1.0):
                if key.data == "wake":
                    return
                if key.data == "listen":
                    self._accept()
                    continue
                conn, side = key.data
                sock = key.fileobj
                if sock is not (conn.rover if side == "rover" else conn.broker):
                    continue  # closed earlier in this round
                assert isinstance(sock, socket.socket)
                try:
                    data = sock.recv(65536)
                except OSError:
                    data = b""
                with self._cond:
                    if data:
                        self._ingest(conn, side, data)
                    else:
                        self._ended(conn, side)
                    self._cond.notify_all()

    def _accept(self) -> None:
        rover, _ = self._listener.accept()
        try:
            broker = socket.create_connection(self._broker, timeout=5.0)
        except OSError:
            rover.close()  # no broker: the firmware sees its connection end and retries later
            return
        for s in (rover, broker):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.setblocking(True)
        with self._cond:
            conn = _Connection(rover, broker, self.model.connection(), len(self.log.delivered))
            self._connections.append(conn)
            self.log.delivered.append(Counter())
        self._selector.register(rover, selectors.EVENT_READ, (conn, "rover"))
        self._selector.register(broker, selectors.EVENT_READ, (conn, "broker"))

    def _ingest(self, conn: _Connection, side: str, data: bytes) -> None:
        now = self._clock_s()
        way = conn.way_from(side)
        way.buffer += data
        try:
            packets = split_packets(way.buffer)
        except MalformedPacket:
            self._ended(conn, side)
            return
        for packet in packets:
            kind = packet[0] >> 4
            flow = _NAMES.get(kind, str(kind))
            at_once = conn.awaiting_ack > 0  # the firmware is blocked in a handshake: the clock cannot move
            if way is conn.up and kind in (CONNECT, SUBSCRIBE):
                conn.awaiting_ack += 1
                at_once = True
            elif way is conn.down and kind in (CONNACK, SUBACK):
                conn.awaiting_ack = max(0, conn.awaiting_ack - 1)
                conn.subscribed |= kind == SUBACK
            elif way is conn.down and kind == PUBLISH:
                flow, payload = publish_topic_payload(packet)
                self._seen[flow] = payload
            self._carry(conn, way, packet, now, flow, at_once or self.transparent)

    def _carry(self, conn: _Connection, way: _Way, packet: bytes, now: float, flow: str, at_once: bool) -> None:
        """Queue a packet for when the link delivers it (or hand it over now, after what is queued before it)."""
        pose = way is conn.down and flow.endswith("/pose")
        if conn.target(way) is None:
            self.log.poses_lost += pose and self._counting
            return
        if at_once:
            way.queue.append(_Queued(now, packet, flow))
            self._flush(conn, way, math.inf)
            return
        before = way.stream.retransmitted
        due = way.stream.deliver(now, flow)
        if pose:
            self.log.poses_retransmitted += way.stream.retransmitted - before
            if due is None:
                self.log.poses_lost += self._counting
            else:
                self.log.pose_delays_s.append(due - now)
        if due is not None:
            way.queue.append(_Queued(due, packet, flow))

    def _flush(self, conn: _Connection, way: _Way, now_s: float) -> bool:
        """Write what is due by ``now_s``; True when something was written."""
        wrote = False
        while way.queue and way.queue[0].due_s <= now_s:
            item = way.queue.popleft()
            target = conn.target(way)
            if target is None:
                way.queue.clear()
                break
            if item.packet == _CLOSE:
                # Shut down, not close: this may run on the loop's thread while the relay's thread selects on the
                # socket; the relay's thread sees the end and closes it.
                _shutdown(target)
                break
            if _send(target, item.packet):
                wrote = True
                if way is conn.down:
                    self.log.delivered[conn.index][item.flow] += 1
        return wrote

    def _ended(self, conn: _Connection, side: str) -> None:
        """One side closed its end: the close crosses the air to the other side in order, like data."""
        now = self._clock_s()
        sock = conn.close_side(side)
        if sock is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(sock)
            sock.close()
        if side == "rover":  # what was on its way to the rover has nowhere to go
            if self._counting:
                self.log.poses_lost += sum(1 for q in conn.down.queue if q.flow.endswith("/pose"))
            conn.down.queue.clear()
        toward = conn.way_from(side)
        if self.transparent:
            toward.queue.append(_Queued(now, _CLOSE, "close"))
        else:
            due = toward.stream.deliver(now, "close")
            if due is not None:
                toward.queue.append(_Queued(due, _CLOSE, "close"))
        self._flush(conn, toward, now)
        self._forget(conn)

    def _forget(self, conn: _Connection) -> None:
        if conn.rover is None and conn.broker is None and conn in self._connections:
            self._connections.remove(conn)


def _shutdown(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):  # already gone
        sock.shutdown(socket.SHUT_RDWR)


def _send(sock: socket.socket, packet: bytes) -> bool:
    try:
        sock.sendall(packet)
    except OSError:
        return False  # the other end is gone; its reader sees the close
    return True


_SIOCOUTQNSD = 0x894B  # Linux: bytes in a TCP socket's send queue not yet sent


def _wait_sent(sock: socket.socket, timeout_s: float = 0.5) -> None:
    """Until every byte written to ``sock`` has left its send queue (Linux SIOCOUTQNSD is 0). Over loopback a
    segment sent is in the peer's receive queue when the send returns (the loopback device hands it over in the
    same call), so the firmware's next read gets it; waiting for the peer's acknowledgement instead would wait for
    its delayed ACK (up to 40 ms). The kernel offers no event for either, so this polls; it rarely has to."""
    unsent = array.array("i", [0])
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            fcntl.ioctl(sock.fileno(), _SIOCOUTQNSD, unsent, True)
        except OSError:
            return
        if unsent[0] == 0:
            return
        time.sleep(0.0001)
