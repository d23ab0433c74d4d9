# Host stand-in for MicroPython's `network` on the ESP8266: a station interface that is associated unless a test
# drops it, and an access point interface that is on, as after an erase. Runs under CPython and MicroPython.

STA_IF = 0
AP_IF = 1
_ap = {"active": True}  # the access point of this "chip" (one per process: tests read it)
_sta = {"pm": None}  # the power management last asked of a station interface


class WLAN:
    """`isconnected()` is True until `drop()`; `connect()` brings it back while the access point is `reachable`.
    Each instance is its own station."""

    PM_NONE = 0
    PM_PERFORMANCE = 1
    PM_POWERSAVE = 2

    def __init__(self, interface_id=STA_IF):
        self.interface_id = interface_id
        self._active = True
        self._connected = True
        self.connect_calls = 0
        self.reachable = True  # False: the access point is gone, connect() associates with nothing (tests)
        self.pm = WLAN.PM_PERFORMANCE  # the ESP8266 boots with modem sleep on

    def active(self, is_active=None):
        if self.interface_id == AP_IF:
            if is_active is None:
                return _ap["active"]
            _ap["active"] = bool(is_active)
            return None
        if is_active is None:
            return self._active
        self._active = bool(is_active)
        return None

    def config(self, **kwargs):
        for key in kwargs:
            if key != "pm":
                raise ValueError("unknown config param")
            self.pm = kwargs[key]
            if self.interface_id == STA_IF:
                _sta["pm"] = self.pm

    def connect(self, ssid=None, key=None):
        self.connect_calls += 1
        self._connected = self.reachable

    def disconnect(self):
        self._connected = False

    def isconnected(self):
        return self._active and self._connected

    def drop(self):
        """Simulate losing the access point (tests)."""
        self._connected = False


def ap_active():
    """Whether the access point interface is on (tests)."""
    return _ap["active"]


def station_pm():
    """The power management last set on a station interface (tests)."""
    return _sta["pm"]
