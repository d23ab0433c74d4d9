"""Host stand-in for MicroPython's ``network``: a station interface that is associated unless a test drops it."""

from __future__ import annotations

STA_IF = 0
AP_IF = 1


class WLAN:
    """The host has a network: ``isconnected()`` is True until ``drop()``; ``connect()`` brings it back."""

    def __init__(self, interface_id: int = STA_IF) -> None:
        self.interface_id = interface_id
        self._active = True
        self._connected = True
        self.connect_calls = 0

    def active(self, is_active: bool | None = None) -> bool | None:
        if is_active is None:
            return self._active
        self._active = bool(is_active)
        return None

    def connect(self, ssid: str | None = None, key: str | None = None) -> None:
        self.connect_calls += 1
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def isconnected(self) -> bool:
        return self._active and self._connected

    def drop(self) -> None:
        """Simulate losing the access point (tests)."""
        self._connected = False
