# Wi-Fi and MQTT for one rover, with the umqtt.simple frozen into MicroPython v1.28.0 (umqtt.simple 1.7.0).
#
# poll(now_ms), once per loop iteration, never waits and never raises:
#   - radio: the access point interface off (after an erase MicroPython runs an open-ish AP), the station's power
#     saving off (modem sleep holds frames for up to a DTIM period: gaps the 100 ms fade would turn into slow-downs);
#     joins Wi-Fi (the ESP8266 keeps retrying on its own; connect is re-issued every 10 s while down);
#   - connects to the broker with a last will (retained status "offline" on ips/v2/rovers/<id>/status), calls
#     on_connect() after CONNACK and before SUBSCRIBE, subscribes to every rover's pose and to the formation;
#   - hands over what arrived (the callback gets every message, up to 16 a poll: a PINGRESP in the middle of a
#     backlog does not end the drain, although umqtt's check_msg() returns None for it as when nothing is there),
#     sends its own keepalive pings (umqtt.simple sends none), and declares the link dead when the broker has been
#     silent for 1.5 keepalives (PINGRESP included);
#   - after a drop: closes the socket, retries with exponential backoff (0.25 s doubling to 8 s), and subscribes
#     again on every new session (umqtt.robust reconnects but does not resubscribe).
#
# umqtt.simple blocks: after a packet's first byte wait_msg() makes the socket blocking without a timeout, it reads
# a whole payload before anyone sees its size, and publish()/ping() write to that blocking socket. So once connected
# the client's socket is a _Stream, which
#   - keeps the real socket non-blocking and frames packets itself into one buffer allocated at start: umqtt gets a
#     packet's first byte only when the whole packet is in that buffer, so its reads never wait;
#   - drops a packet longer than the largest message the rover accepts without reading it into RAM (its bytes are
#     read into a small scratch buffer and forgotten, as many as have arrived, at each poll);
#   - waits only where MQTT makes it (SUBACK, or room in the send buffer), with the motors made safe first (`safe`),
#     and for at most broker.timeout_s, then raises OSError and the link drops.
# The connect itself runs on umqtt's own socket with connect(timeout=broker.timeout_s), which 1.7.0 applies to every
# operation of the connect (TCP connect, CONNECT, CONNACK); the motors are made safe first. A broker given by name
# is looked up once (DNS cannot be given a timeout); give an address to avoid even that.
import time

import msg
import network
from micropython import const
from umqtt import simple

_BACKOFF_MIN_MS = const(250)
_BACKOFF_MAX_MS = const(8000)
_WIFI_RETRY_MS = const(10000)
_DRAIN_MAX = const(16)  # messages handled per poll, so one poll cannot starve the control step
_ETIMEDOUT = const(110)
# The longest packet kept: a formation (the largest message the rover accepts) with its topic, QoS 1 packet id and
# fixed header. Anything longer is dropped unread.
_MAX_PACKET = const(5 + 2 + 16 + 2 + 512)
_PUBLISH = const(0x30)
_EMPTY = memoryview(b"")


def _nothing():
    pass


class _Stream:
    """What umqtt.simple sees as its socket once connected: MQTT packets framed without waiting (see above)."""

    def __init__(self, safe):
        self.safe = safe
        self.patience_ms = 2000
        self.until = None  # ticks after which nothing more may wait (a SUBSCRIBE while PUBLISHes keep coming)
        self.sock = None
        self.blocking = True
        self.heard = False  # any byte from the broker since the link last looked
        self.idle = False  # umqtt asked for a packet and none had arrived whole
        self.dropped = 0  # packets dropped for their length
        self.dropped_bytes = 0  # the length of the last one
        self.waits = 0  # times a call had to wait (motors made safe first)
        self._mv = memoryview(bytearray(_MAX_PACKET))  # the packet buffer, read and written through this view
        self._one = bytearray(1)  # each fixed-header byte is read here, then put in its place in the buffer
        self._out = _EMPTY  # what write() has still to send
        self._reset()

    def _reset(self):
        self._n = 0  # bytes of the packet in the buffer
        self._need = -1  # its whole length once the fixed header is complete
        self._pos = -1  # next byte handed to umqtt; -1: not handing one over
        self._skip = 0  # bytes of a dropped packet still to discard

    def attach(self, sock):
        self.sock = sock
        self._reset()
        self.blocking = True
        self.heard = False
        sock.setblocking(False)

    # -- framing, never waiting ----------------------------------------------------------------------------------
    def _take(self, view, n=_MAX_PACKET):
        k = self.sock.readinto(view, n)  # type: ignore[union-attr]
        if k is None:
            return 0
        if k == 0:
            raise OSError(-1)  # the broker closed the connection
        self.heard = True
        return k

    def _pump(self):
        """Read what has arrived without waiting; True when a whole packet is in the buffer."""
        while True:
            if self._skip > 0:  # a dropped packet's bytes go through the buffer, which holds nothing meanwhile
                k = self._take(self._mv, min(self._skip, _MAX_PACKET))
                if k == 0:
                    return False
                self._skip -= k
                continue
            if self._need >= 0:
                if self._n < self._need:
                    self._n += self._take(self._mv[self._n : self._need])
                return self._n >= self._need
            # The fixed header, a byte at a time: type, then 1-4 bytes of remaining length.
            if self._take(self._one, 1) == 0:
                return False
            self._mv[self._n] = self._one[0]
            self._n += 1
            if self._n == 1:
                continue
            if self._mv[self._n - 1] & 0x80:
                if self._n == 5:
                    raise OSError(-2)  # a remaining length of more than four bytes: not MQTT
                continue
            length = 0
            for i in range(self._n - 1, 0, -1):
                length = (length << 7) | (self._mv[i] & 0x7F)
            if self._n + length > _MAX_PACKET:
                self.dropped += 1
                self.dropped_bytes = length
                self._n = 0
                self._skip = length
            else:
                self._need = self._n + length

    def _wait(self, ready):
        # Anything that waits makes the motors safe first, and gives up after patience_ms, or at `until`.
        self.safe()
        self.waits += 1
        end = time.ticks_add(time.ticks_ms(), self.patience_ms)
        if self.until is not None and time.ticks_diff(self.until, end) < 0:
            end = self.until
        while not ready():
            if time.ticks_diff(time.ticks_ms(), end) >= 0:
                raise OSError(_ETIMEDOUT)
            time.sleep_ms(1)

    # -- the socket interface umqtt.simple uses --------------------------------------------------------------------
    def read(self, n):
        if self._pos < 0:  # umqtt asks for a new packet's first byte
            if not self._pump():
                if not self.blocking:
                    self.idle = True
                    return None
                self._wait(self._pump)
            self._pos = 0
        end = min(self._pos + n, self._need)
        data = bytes(self._mv[self._pos : end])
        self._pos = end
        if end >= self._need:
            self._reset()
        return data

    def write(self, buf, n=None):
        view = memoryview(buf)
        if n is not None:
            view = view[:n]
        self._out = view
        if not self._send():
            self._wait(self._send)
        self._out = _EMPTY
        return len(view)

    def _send(self):
        k = self.sock.write(self._out)  # type: ignore[union-attr]
        if k:
            self._out = self._out[k:]
        return len(self._out) == 0

    def setblocking(self, flag):
        self.blocking = flag

    def settimeout(self, t):
        self.blocking = t is None or t > 0

    def close(self):
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class Link:
    """One rover's broker connection. on_message(topic, payload) receives every message (bytes, bytes);
    on_connect() is called on every new session, after CONNACK and before SUBSCRIBE; safe() (the motors off) before
    anything that may wait."""

    def __init__(self, cfg, on_message, on_connect=None, log=print, safe=None):
        self.id = cfg["id"]
        b = cfg["broker"]
        w = cfg["wifi"]
        self.log = log
        self.on_connect = on_connect
        self.keepalive_ms = b["keepalive_s"] * 1000
        self.timeout_s = b["timeout_s"]
        self.ssid = w["ssid"]
        self.wifi_password = w["password"]
        user = b["user"] or None
        password = b["password"] or None
        self.client = simple.MQTTClient(
            ("rover-" + self.id).encode(),
            b["host"],  # the client's server: resolved to an address at the first connect when it is a name
            b["port"],
            user=None if user is None else user.encode(),
            password=b"" if password is None else password.encode(),
            keepalive=b["keepalive_s"],
        )
        self.client.set_callback(on_message)
        self.status_topic = msg.status_topic(self.id)
        offline = msg.rover_status(self.id, "offline", "disconnected", None, None, None)
        self.client.set_last_will(self.status_topic, offline, True, 1)
        self.stream = _Stream(safe or _nothing)  # its safe() is the link's too
        network.WLAN(network.AP_IF).active(False)
        self.wlan = network.WLAN(network.STA_IF)
        self.wlan.active(True)
        self.wlan.config(pm=network.WLAN.PM_NONE)
        self.up = False
        self.connects = 0
        self.drops = 0
        self._dropped = 0
        self._retry_at = 0
        self._backoff_ms = _BACKOFF_MIN_MS
        self._wifi_at = None
        self._ping_at = 0
        self._heard_at = 0
        self._now = 0

    # -- Wi-Fi ---------------------------------------------------------------------------------------------------
    def _wifi(self, now_ms):
        if self.wlan.isconnected():
            return True
        # (a tick difference below 0: the last try was more than 2**29 ms ago, and the ticks wrapped since)
        if self._wifi_at is None or not 0 <= time.ticks_diff(now_ms, self._wifi_at) < _WIFI_RETRY_MS:
            self._wifi_at = now_ms
            self.wlan.active(True)
            if self.ssid:
                self.wlan.connect(self.ssid, self.wifi_password)  # returns at once; isconnected() tells later
        return False

    # -- MQTT ----------------------------------------------------------------------------------------------------
    def _connect(self, now_ms):
        s = self.stream
        s.safe()  # a connect may take up to timeout_s (a name lookup longer)
        c = self.client
        if not _numeric(c.server):  # type: ignore[attr-defined]
            c.server = simple.socket.getaddrinfo(c.server, c.port)[0][-1][0]  # type: ignore[attr-defined]
        c.connect(True, self.timeout_s)
        s.attach(c.sock)  # type: ignore[attr-defined]
        s.patience_ms = int(self.timeout_s * 1000)
        c.sock = s  # type: ignore[attr-defined]
        self.up = True
        self.connects += 1
        self._ping_at = now_ms
        self._heard_at = now_ms
        if self.on_connect is not None:
            self.on_connect()
        # umqtt's subscribe() hands over PUBLISHes until its SUBACK comes: both together get timeout_s.
        s.until = time.ticks_add(time.ticks_ms(), s.patience_ms)
        try:
            c.subscribe(msg.POSE_WILDCARD)
            c.subscribe(msg.FORMATION_TOPIC, 1)
        finally:
            s.until = None
        self._backoff_ms = _BACKOFF_MIN_MS
        self.log("broker connected", self.connects)

    def _drop(self, now_ms, why):
        was_up = self.up
        self.up = False
        try:
            if self.client.sock is not None:  # type: ignore[attr-defined]
                self.client.sock.close()  # type: ignore[attr-defined]
        except Exception:  # the socket is already broken; closing it is housekeeping
            pass
        self.client.sock = None  # type: ignore[attr-defined]
        self._retry_at = time.ticks_add(now_ms, self._backoff_ms)
        self._backoff_ms = min(self._backoff_ms * 2, _BACKOFF_MAX_MS)
        if was_up:
            self.drops += 1
        self.log("broker link down:", why)

    def poll(self, now_ms):
        """Keep the link alive and hand over what arrived. Returns True when connected."""
        self._now = now_ms
        try:
            if not self._wifi(now_ms):
                if self.up:
                    self._drop(now_ms, "wifi lost")
                return False
            if not self.up:
                # Waiting while the retry time lies at most a backoff ahead: one further ahead is one the tick
                # differences wrapped past (an outage of days, or the 0 it starts at read by ticks past 2**29).
                if 0 < time.ticks_diff(self._retry_at, now_ms) <= _BACKOFF_MAX_MS:
                    return False
                self._connect(now_ms)
            s = self.stream
            for _ in range(_DRAIN_MAX):
                s.idle = False
                op = self.client.check_msg()
                if op is None:
                    if s.idle:
                        break
                    continue  # a PINGRESP: more may wait behind it
                if op & 0xF0 != _PUBLISH:
                    raise OSError(-3)  # a packet the session does not expect: start afresh
            if s.dropped != self._dropped:
                self._dropped = s.dropped
                self.log("dropped a packet of", s.dropped_bytes, "bytes (longest kept:", _MAX_PACKET, ")")
            if s.heard:
                s.heard = False
                self._heard_at = now_ms
            elif time.ticks_diff(now_ms, self._heard_at) > self.keepalive_ms * 3 // 2:
                self._drop(now_ms, "broker silent")
                return False
            if time.ticks_diff(now_ms, self._ping_at) >= self.keepalive_ms // 2:
                self.client.ping()
                self._ping_at = now_ms
            return True
        except Exception as e:  # OSError (socket, timeout), MQTTException, AssertionError on a bad reply
            self._drop(now_ms, repr(e))
            return False

    def publish_status(self, payload):
        """Retained status on the rover's own topic (the only topic its ACL allows)."""
        if self.up:
            try:
                self.client.publish(self.status_topic, payload, True, 0)
            except Exception as e:
                self._drop(self._now, repr(e))

    def close(self, payload=None):
        """Clean shutdown, without waiting: publish `payload` (the offline status) first, since a clean DISCONNECT
        fires no will; if the send buffer is full, the broker's will says offline instead."""
        if self.up:
            self.stream.patience_ms = 0
            try:
                if payload is not None:
                    self.client.publish(self.status_topic, payload, True, 0)
                self.client.disconnect()
            except Exception:  # going away anyway; the broker's will covers an unclean end
                pass
        self.up = False


def _numeric(host):
    for ch in host:
        if ch not in "0123456789.":
            return False
    return True
