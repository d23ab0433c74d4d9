# Wi-Fi and MQTT for one rover, with umqtt.simple (frozen into the ESP8266 firmware).
#
# poll(now_ms), once per loop iteration, never blocks for long and never raises:
#   - joins Wi-Fi (the ESP8266 keeps retrying on its own; we re-issue connect every 10 s while down);
#   - connects to the broker with a last will (retained status "offline" on ips/v1/rovers/<id>/status), subscribes
#     to every rover's pose and to the formation, and publishes "online" (the rover does that: Rover._report);
#   - drains what arrived (the callback gets every message), sends its own keepalive pings (umqtt.simple sends none),
#     and declares the link dead when the broker has been silent for 1.5 keepalives (PINGRESP included);
#   - after a drop: closes the socket and retries with exponential backoff (0.25 s doubling to 8 s), and
#     subscribes again on every new session (umqtt.robust reconnects but does not resubscribe).
import msg
import network
from micropython import const
from umqtt.simple import MQTTClient

_BACKOFF_MIN_MS = const(250)
_BACKOFF_MAX_MS = const(8000)
_WIFI_RETRY_MS = const(10000)
_DRAIN_MAX = const(16)  # messages handled per poll, so one poll cannot starve the control step
_TICKS_PERIOD = const(1 << 30)
_TICKS_HALF = const(1 << 29)


def _tdiff(a, b):
    return ((a - b + _TICKS_HALF) & (_TICKS_PERIOD - 1)) - _TICKS_HALF


class _Heard:
    """Wraps the client's socket to notice any byte from the broker: check_msg() returns None both for "nothing"
    and for a PINGRESP, and a half-open TCP connection (Wi-Fi gone quiet) would otherwise look healthy for minutes."""

    def __init__(self, sock):
        self.sock = sock
        self.heard = False

    def read(self, n):
        data = self.sock.read(n)
        if data:
            self.heard = True
        return data

    def write(self, buf, n=None):
        if n is None:
            return self.sock.write(buf)
        return self.sock.write(buf, n)

    def setblocking(self, flag):
        self.sock.setblocking(flag)

    def settimeout(self, t):
        self.sock.settimeout(t)

    def close(self):
        self.sock.close()


class Link:
    """One rover's broker connection. on_message(topic, payload) receives every message (bytes, bytes);
    on_connect() is called after each CONNACK, before the subscriptions (the rover forgets its formation there)."""

    def __init__(self, cfg, on_message, on_connect=None, log=print):
        self.id = cfg["id"]
        b = cfg["broker"]
        w = cfg["wifi"]
        self.log = log
        self.keepalive_ms = b["keepalive_s"] * 1000
        self.timeout_s = b["timeout_s"]
        self.ssid = w["ssid"]
        self.wifi_password = w["password"]
        user = b["user"] or None
        password = b["password"] or None
        self.client = MQTTClient(
            ("rover-" + self.id).encode(),
            b["host"],
            b["port"],
            user=None if user is None else user.encode(),
            password=b"" if password is None else password.encode(),
            keepalive=b["keepalive_s"],
        )
        self.client.set_callback(on_message)
        self.status_topic = msg.status_topic(self.id)
        offline = msg.rover_status(self.id, "offline", "disconnected", None, None, None)
        self.client.set_last_will(self.status_topic, offline, retain=True, qos=1)
        self.on_connect = on_connect
        self.wlan = network.WLAN(network.STA_IF)
        self.up = False
        self.connects = 0
        self.drops = 0
        self._heard = None
        self._retry_at = 0
        self._backoff_ms = _BACKOFF_MIN_MS
        self._wifi_at = None
        self._ping_at = 0
        self._heard_at = 0
        self._timeout_ok = True
        self._now = 0

    # -- Wi-Fi ---------------------------------------------------------------------------------------------------
    def _wifi(self, now_ms):
        if self.wlan.isconnected():
            return True
        if self._wifi_at is None or _tdiff(now_ms, self._wifi_at) >= _WIFI_RETRY_MS:
            self._wifi_at = now_ms
            self.wlan.active(True)
            if self.ssid:
                self.wlan.connect(self.ssid, self.wifi_password)  # returns at once; isconnected() tells later
        return False

    # -- MQTT ----------------------------------------------------------------------------------------------------
    def _connect(self, now_ms):
        c = self.client
        if self._timeout_ok:
            try:
                c.connect(True, self.timeout_s)
            except TypeError:  # an older frozen umqtt.simple: connect(clean_session) only
                self._timeout_ok = False
                c.connect(True)
        else:
            c.connect(True)
        # `sock` is a plain attribute of umqtt.simple.MQTTClient; the stub does not declare it.
        self._heard = _Heard(c.sock)  # type: ignore[attr-defined]
        c.sock = self._heard  # type: ignore[attr-defined]
        if self.on_connect is not None:
            self.on_connect()
        c.subscribe(msg.POSE_WILDCARD)
        c.subscribe(msg.FORMATION_TOPIC, 1)
        self.up = True
        self.connects += 1
        self._backoff_ms = _BACKOFF_MIN_MS
        self._ping_at = now_ms
        self._heard_at = now_ms
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
        self._retry_at = now_ms + self._backoff_ms
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
                if _tdiff(now_ms, self._retry_at) < 0:
                    return False
                self._connect(now_ms)
            for _ in range(_DRAIN_MAX):
                if self.client.check_msg() is None:
                    break
            heard = self._heard
            if heard is not None and heard.heard:
                heard.heard = False
                self._heard_at = now_ms
            elif _tdiff(now_ms, self._heard_at) > self.keepalive_ms * 3 // 2:
                self._drop(now_ms, "broker silent")
                return False
            if _tdiff(now_ms, self._ping_at) >= self.keepalive_ms // 2:
                self.client.ping()
                self._ping_at = now_ms
            return True
        except Exception as e:  # OSError (socket), MQTTException, IndexError/AssertionError on a torn packet
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
        """Clean shutdown: publish `payload` (the offline status) first, since a clean DISCONNECT fires no will."""
        if self.up:
            try:
                if payload is not None:
                    self.client.publish(self.status_topic, payload, True, 0)
                self.client.disconnect()
            except Exception:  # going away anyway; the broker's will covers an unclean end
                pass
        self.up = False
