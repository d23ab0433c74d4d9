# A simulated clock and a scripted MQTT broker behind a MicroPython-style socket module, so the rover's real app,
# link and umqtt.simple run against a network that stalls where a test says, in simulated time, under CPython and
# inside MicroPython alike (firmware/harness/mpy/stall.py drives them; no typing, no __future__).
#
# The socket behaves like lwip's on the ESP8266 (extmod/modlwip.c): non-blocking reads return what has arrived or
# None, blocking ones wait (the clock runs) up to the timeout and then raise OSError(ETIMEDOUT), without a timeout
# for ever; writes take what fits in the send buffer, None when nothing does. Computation takes no simulated time:
# the clock moves only in sleep_ms() and in socket waits, one millisecond at a time, firing machine timers and
# watchers as it goes.
import machine

ETIMEDOUT = 110
ECONNREFUSED = 111
MASK = 0x3FFFFFFF


class Clock:
    """time.ticks_ms/ticks_diff/ticks_add/sleep_ms over simulated milliseconds (ticks wrap at 2**30 as on the chip)."""

    def __init__(self, start_ms=0):
        self.now = start_ms
        self.watchers = []  # f(now_ms), every simulated millisecond
        self.interrupt_at = None  # a KeyboardInterrupt at the first millisecond at or after this time (Ctrl-C)
        self.limit = None  # a guard: raises RuntimeError past this time (a wait that never ends)

    def ticks_ms(self):
        return self.now & MASK

    def ticks_add(self, t, delta):
        return (t + delta) & MASK

    def ticks_diff(self, a, b):
        d = (a - b) & MASK
        if d >= 0x20000000:
            return d - MASK - 1
        return d

    def sleep_ms(self, ms):
        for _ in range(ms):
            self.tick()

    def tick(self):
        self.now += 1
        machine.run_timers(self.now)
        for w in self.watchers:
            w(self.now)
        if self.interrupt_at is not None and self.now >= self.interrupt_at:
            self.interrupt_at = None
            raise KeyboardInterrupt()
        if self.limit is not None and self.now > self.limit:
            raise RuntimeError("simulated time ran past its limit")


def packet(first, body):
    """An MQTT packet: first byte, remaining length, body."""
    n = len(body)
    head = bytearray([first])
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            head.append(b | 0x80)
        else:
            head.append(b)
            break
    return bytes(head) + body


def publish_packet(topic, payload, qos=0, pid=1, retain=False):
    body = bytes([len(topic) >> 8, len(topic) & 0xFF]) + topic
    if qos:
        body += bytes([pid >> 8, pid & 0xFF])
    return packet(0x30 | (qos << 1) | (1 if retain else 0), body + payload)


class Broker:
    """The far end of the rover's TCP connections, scripted: what it answers, when bytes arrive, where they stop.

    Bytes for the rover are queued with their arrival time (`send`); `cut_at` (a count of rover-bound bytes) is where
    the Wi-Fi drops: nothing after it ever arrives, and the rover's writes fill the send buffer (`room`, bytes) and
    then stall. `answers` False: the TCP connection is taken and nothing is ever said."""

    def __init__(self, clock):
        self.clock = clock
        self.queue = []  # [arrival ms, bytes] for the rover, in order
        self.queued = 0  # rover-bound bytes queued on this connection (stream offset)
        self.delivered = []  # rover-bound bytes that reached the rover, per connection
        self.cut_at = None
        self.answers = True
        self.answers_subscribe = True
        self.refuse = False
        self.room = -1  # bytes the rover may still write; -1: no limit
        self.retained = None  # the retained formation payload
        self.latency_ms = 2
        self.hold_until = None  # nothing arrives before this time (an outage that TCP rides out)
        self.conn = None
        self.connections = 0
        self.subscribed = []
        self.published = []  # (topic, payload) the rover sent
        self.disconnects = 0
        self.pings = 0
        self._rx = bytearray()
        self._pid = 0

    # -- towards the rover ---------------------------------------------------------------------------------------
    def send(self, data, delay_ms=None):
        """Queue bytes for the rover; they arrive delay_ms from now (and after what is already queued)."""
        at = self.clock.now + (self.latency_ms if delay_ms is None else delay_ms)
        if self.hold_until is not None and at < self.hold_until:
            at = self.hold_until
        if self.queue and self.queue[-1][0] > at:
            at = self.queue[-1][0]
        self.queue.append([at, data])
        self.queued += len(data)
        return at

    def publish(self, topic, payload, qos=0):
        """A PUBLISH to the rover, if it subscribed to the topic (a trailing /+/... wildcard is understood)."""
        if self.conn is None or not self._matches(topic):
            return None
        pid = 0
        if qos:
            self._pid = self._pid % 65535 + 1
            pid = self._pid
        return self.send(publish_packet(topic, payload, qos, pid))

    def _matches(self, topic):
        for t in self.subscribed:
            if t == topic:
                return True
            if t.endswith(b"/+/pose") and topic.startswith(t[:-6]) and topic.endswith(b"/pose"):
                return True
        return False

    # -- from the rover ------------------------------------------------------------------------------------------
    def receive(self, data):
        self._rx += data
        while len(self._rx) >= 2:
            n = 0
            shift = 0
            i = 1
            while True:
                if i >= len(self._rx):
                    return
                b = self._rx[i]
                n |= (b & 0x7F) << shift
                shift += 7
                i += 1
                if not b & 0x80:
                    break
            if len(self._rx) < i + n:
                return
            self._handle(self._rx[0], bytes(self._rx[i : i + n]))
            self._rx = self._rx[i + n :]

    def _handle(self, first, body):
        kind = first & 0xF0
        if kind == 0x10:  # CONNECT
            if self.answers:
                self.send(b"\x20\x02\x00\x00")
        elif kind == 0x80:  # SUBSCRIBE
            topic = body[4 : 4 + (body[2] << 8 | body[3])]
            self.subscribed.append(topic)
            if self.answers and self.answers_subscribe:
                self.send(b"\x90\x03" + body[0:2] + bytes([body[-1]]))
                if topic == b"ips/v1/formation" and self.retained is not None:
                    self._pid = self._pid % 65535 + 1
                    self.send(publish_packet(topic, self.retained, 1, self._pid, True))
        elif kind == 0xC0:  # PINGREQ
            self.pings += 1
            if self.answers:
                self.send(b"\xd0\x00")
        elif kind == 0x30:  # PUBLISH (the rover's status)
            n = body[0] << 8 | body[1]
            self.published.append((bytes(body[2 : 2 + n]), bytes(body[2 + n + (2 if first & 6 else 0) :])))
        elif kind == 0xE0:  # DISCONNECT
            self.disconnects += 1

    def connected(self, sock):
        self.conn = sock
        self.connections += 1
        self.delivered.append(0)
        self.subscribed = []
        self._rx = bytearray()
        self.queue = []
        self.queued = 0

    def arrived(self, sock):
        """Move what has arrived by now into the socket's buffer (nothing past cut_at)."""
        if sock is not self.conn:
            return
        while self.queue and self.queue[0][0] <= self.clock.now:
            at, data = self.queue.pop(0)
            if self.cut_at is not None:
                left = self.cut_at - sock.offset
                if left <= 0:
                    self.queue = []
                    return
                data = data[:left]
            sock.buf += data
            sock.offset += len(data)
            self.delivered[-1] = sock.offset


class Socket:
    """A MicroPython (lwip) socket connected to the Broker."""

    def __init__(self, broker):
        self.broker = broker
        self.timeout = None  # None: blocking; 0: non-blocking; else seconds
        self.buf = bytearray()
        self.pos = 0  # next byte of buf to hand over
        self.offset = 0  # rover-bound bytes received on this connection
        self.open = True

    def settimeout(self, t):
        self.timeout = t

    def setblocking(self, flag):
        self.timeout = None if flag else 0

    def connect(self, addr):
        if self.broker.refuse:
            raise OSError(ECONNREFUSED)
        self.broker.connected(self)

    def _wait(self, ready):
        # lwip's wait: the event loop runs (the clock here), a timeout raises ETIMEDOUT
        if self.timeout == 0:
            return False
        t0 = self.broker.clock.now
        while not ready():
            if self.timeout is not None and self.broker.clock.now - t0 >= self.timeout * 1000:
                raise OSError(ETIMEDOUT)
            self.broker.clock.tick()
            self.broker.arrived(self)
        return True

    def _has_data(self):
        return len(self.buf) > self.pos

    def readinto(self, buf, n=None):
        if not self.open:
            raise OSError(9)
        self.broker.arrived(self)
        want = len(buf) if n is None else min(n, len(buf))
        if len(self.buf) <= self.pos and not self._wait(self._has_data):
            return None
        k = min(want, len(self.buf) - self.pos)
        data = self.buf
        pos = self.pos
        for i in range(k):  # byte by byte: no slice to allocate, as lwip copies out of its buffers
            buf[i] = data[pos + i]
        self.pos = pos + k
        if self.pos > 4096:
            self.buf = self.buf[self.pos :]
            self.pos = 0
        return k

    def read(self, n):
        out = bytearray()
        while len(out) < n:
            part = bytearray(n - len(out))
            k = self.readinto(part)
            if k is None:
                return bytes(out) if out else None
            out += part[:k]
        return bytes(out)

    def _has_room(self):
        return self.broker.room != 0

    def write(self, buf, n=None):
        if not self.open:
            raise OSError(9)
        data = bytes(buf if n is None else buf[:n])
        if self.broker.room == 0 and not self._wait(self._has_room):
            return None
        k = len(data) if self.broker.room < 0 else min(len(data), self.broker.room)
        if self.broker.room > 0:
            self.broker.room -= k
        if self.broker.cut_at is None:
            self.broker.receive(data[:k])
        return k

    def close(self):
        self.open = False
        if self.broker.conn is self:
            self.broker.conn = None


class SocketModule:
    """What `import socket` gives umqtt.simple: socket() and getaddrinfo() bound to one broker."""

    def __init__(self, broker):
        self.broker = broker
        self.lookups = 0

    def socket(self, *args):
        return Socket(self.broker)

    def getaddrinfo(self, host, port, *args):
        self.lookups += 1
        return [(2, 1, 0, "", ("10.0.0.2", port))]
