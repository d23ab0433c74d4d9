"""A MicroPython-style ``socket`` module over CPython's, for the vendored umqtt.simple and link.py under CPython.

MicroPython sockets are streams, and this keeps their semantics (py/stream.c, extmod/modlwip.c):

- blocking, or with a timeout: ``read(n)`` returns n bytes or fewer at EOF; a timeout with nothing read is
  ``OSError(ETIMEDOUT)``. A blocking socket without a timeout gives up after ``BLOCKING_TIMEOUT_S`` here, so a test
  cannot hang on a dead broker (the chip would wait for ever);
- non-blocking: ``read(n)``/``readinto(buf)`` return what has arrived, ``None`` when nothing has, ``b""``/0 at EOF;
  ``write(buf)`` returns the bytes taken, ``None`` when none could be.
"""

from __future__ import annotations

import errno
import socket as _socket
from typing import Any

BLOCKING_TIMEOUT_S = 5.0


def getaddrinfo(host: str, port: int, *args: Any) -> list[tuple[Any, ...]]:
    return _socket.getaddrinfo(host, port, _socket.AF_INET, _socket.SOCK_STREAM)


class socket:  # noqa: N801 - the name MicroPython code calls
    def __init__(self, *args: Any) -> None:
        self._s = _socket.socket(_socket.AF_INET, _socket.SOCK_STREAM)
        self._s.setsockopt(_socket.IPPROTO_TCP, _socket.TCP_NODELAY, 1)
        self._timeout: float | None = None  # None: blocking; 0: non-blocking
        self._apply()

    def _apply(self) -> None:
        self._s.settimeout(BLOCKING_TIMEOUT_S if self._timeout is None else self._timeout)

    def connect(self, addr: Any) -> None:
        try:
            self._s.connect(addr)
        except TimeoutError:
            raise OSError(errno.ETIMEDOUT, "connect timed out") from None

    def settimeout(self, t: float | None) -> None:
        self._timeout = t
        self._apply()

    def setblocking(self, flag: bool) -> None:
        self._timeout = None if flag else 0.0
        self._apply()

    def _recv_into(self, view: memoryview) -> int | None:
        """One receive: bytes read, 0 at EOF, None when a non-blocking socket has nothing."""
        try:
            return self._s.recv_into(view)
        except BlockingIOError:
            return None
        except TimeoutError:
            raise OSError(errno.ETIMEDOUT, "timed out") from None

    def readinto(self, buf: bytearray | memoryview, n: int | None = None) -> int | None:
        view = memoryview(buf)
        if n is not None:
            view = view[:n]
        done = 0
        while done < len(view):
            k = self._recv_into(view[done:])
            if k is None:
                return done or None
            if k == 0:
                break
            done += k
        return done

    def read(self, n: int) -> bytes | None:
        buf = bytearray(n)
        k = self.readinto(buf)
        if k is None:
            return None
        return bytes(buf[:k])

    def write(self, buf: bytes | bytearray | memoryview, n: int | None = None) -> int | None:
        data = memoryview(buf)
        if n is not None:
            data = data[:n]
        if self._timeout == 0:
            try:
                return self._s.send(data)
            except BlockingIOError:
                return None
        try:
            self._s.sendall(data)
        except TimeoutError:
            raise OSError(errno.ETIMEDOUT, "timed out") from None
        return len(data)

    def close(self) -> None:
        self._s.close()

    def fileno(self) -> int:
        return self._s.fileno()
