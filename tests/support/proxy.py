"""A TCP proxy a test can cut: the network link between a board and the central broker.

``down()`` closes every connection through it and refuses new ones (the link is gone: both ends see the TCP
connection end, as after a router reboot); ``stall()`` holds what is sent either way, connections open, as a Wi-Fi
link that fades without a reset (both ends notice nothing but silence); ``up()`` lets connections through again,
and delivers what a stall held, late.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from dataclasses import dataclass, field


@dataclass
class Proxy:
    target_port: int
    host: str = "127.0.0.1"
    port: int = 0
    _server: socket.socket | None = None
    _open: bool = True
    _conns: list[socket.socket] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _flowing: threading.Event = field(default_factory=threading.Event)
    connections: int = 0

    def start(self) -> Proxy:
        self._flowing.set()
        server = socket.socket()
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind((self.host, 0))
        server.listen(16)
        self.port = server.getsockname()[1]
        self._server = server
        threading.Thread(target=self._accept, daemon=True).start()
        return self

    def _accept(self) -> None:
        assert self._server is not None
        while True:
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            with self._lock:
                if not self._open:
                    client.close()
                    continue
                try:
                    upstream = socket.create_connection((self.host, self.target_port))
                except OSError:
                    client.close()
                    continue
                for s in (client, upstream):  # a wire adds no delay of its own
                    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._conns += [client, upstream]
                self.connections += 1
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                self._flowing.wait()
                dst.sendall(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)

    def down(self) -> None:
        with self._lock:
            self._open = False
            for s in self._conns:
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
                s.close()
            self._conns.clear()

    def stall(self) -> None:
        self._flowing.clear()

    def up(self) -> None:
        with self._lock:
            self._open = True
        self._flowing.set()

    def stop(self) -> None:
        self.down()
        self._flowing.set()
        if self._server is not None:
            self._server.close()
