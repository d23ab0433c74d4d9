"""A MicroPython-style ``socket`` module over CPython's, for the vendored umqtt.simple under CPython.

MicroPython sockets are streams: ``read(n)`` blocks until n bytes (or EOF) and, when non-blocking, returns None if
nothing is waiting; ``write(buf, n)`` writes the first n bytes. Blocking reads give up after ``BLOCKING_TIMEOUT_S``
(an OSError, as a dead link would raise on the board when the watchdog does not reset it first), so a broker that
dies in the middle of a packet cannot hang a host test.
"""

from __future__ import annotations

import socket as _socket
from typing import Any

BLOCKING_TIMEOUT_S = 5.0


def getaddrinfo(host: str, port: int, *args: Any) -> list[tuple[Any, ...]]:
    return _socket.getaddrinfo(host, port, _socket.AF_INET, _socket.SOCK_STREAM)


class socket:  # noqa: N801 - the name MicroPython code calls
    def __init__(self, *args: Any) -> None:
        self._s = _socket.socket(_socket.AF_INET, _socket.SOCK_STREAM)
        self._s.setsockopt(_socket.IPPROTO_TCP, _socket.TCP_NODELAY, 1)
        self._blocking = True
        self._timeout: float | None = None

    def connect(self, addr: Any) -> None:
        self._s.settimeout(self._timeout if self._timeout is not None else BLOCKING_TIMEOUT_S)
        self._s.connect(addr)
        self._apply()

    def settimeout(self, t: float | None) -> None:
        self._timeout = t
        self._blocking = t is None or t > 0
        self._apply()

    def setblocking(self, flag: bool) -> None:
        self._blocking = bool(flag)
        self._timeout = None
        self._apply()

    def _apply(self) -> None:
        if not self._blocking:
            self._s.setblocking(False)
        else:
            self._s.settimeout(self._timeout if self._timeout is not None else BLOCKING_TIMEOUT_S)

    def read(self, n: int) -> bytes | None:
        if not self._blocking:
            try:
                first = self._s.recv(n)
            except BlockingIOError:
                return None
            if not first or len(first) == n:
                return first
            # MicroPython returns what is there; umqtt reads one byte here, so this is rare. Finish it blocking.
            self._s.settimeout(BLOCKING_TIMEOUT_S)
            try:
                return first + self._read_exactly(n - len(first))
            finally:
                self._apply()
        return self._read_exactly(n)

    def _read_exactly(self, n: int) -> bytes:
        chunks = []
        while n > 0:
            chunk = self._s.recv(n)
            if not chunk:
                break
            chunks.append(chunk)
            n -= len(chunk)
        return b"".join(chunks)

    def write(self, buf: bytes | bytearray | memoryview, n: int | None = None) -> int:
        data = memoryview(buf)
        if n is not None:
            data = data[:n]
        blocking = self._blocking
        if not blocking:
            self._s.settimeout(BLOCKING_TIMEOUT_S)
        try:
            self._s.sendall(data)
        finally:
            if not blocking:
                self._apply()
        return len(data)

    def close(self) -> None:
        self._s.close()

    def fileno(self) -> int:
        return self._s.fileno()
