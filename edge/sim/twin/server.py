"""The lab's socket: camera streams and control requests (the protocol is :mod:`edge.sim.twin.wire`).

A Unix stream socket, mode 0600 in the state directory (only its owner can watch the camera or cause faults). One
thread accepts; each connection has its own thread: a camera reader gets the description of the camera it named
(the first when it names none) and then frames from its own newest-frame slot (a reader slower than the camera
misses frames, it never falls behind); a control request gets one reply.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from edge.errors import EdgeIpsError, SimulationError
from edge.sim.twin.lab import TwinLab
from edge.sim.twin.wire import (
    VERSION,
    frame_header,
    read_line,
    send_line,
)

log = logging.getLogger("edge.sim.twin")

REQUEST_TIMEOUT_S = 5.0  # a client must say what it wants within this
SEND_TIMEOUT_S = 10.0  # a reader that takes no frame for this long is dropped
MAX_WAIT_S = 60.0  # the longest a ``wait`` request holds its connection


def _answers(path: Path) -> bool:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        probe.settimeout(1.0)
        try:
            probe.connect(str(path))
        except OSError:
            return False
    return True


class LabServer:
    """Serves ``lab`` on the Unix socket ``path`` until :meth:`close`. ``last_reader_left`` (monotonic s, None
    while a camera reader is connected) lets the lab's owner end it once nobody watches."""

    def __init__(self, path: Path, lab: TwinLab) -> None:
        self.path = path
        self.lab = lab
        self._sock: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._closed = threading.Event()
        self._readers = 0
        self._lock = threading.Lock()
        self.last_reader_left: float | None = lab.clock()

    def start(self) -> LabServer:
        if self.path.exists():
            if _answers(self.path):
                raise SimulationError(f"{self.path}: a twin lab already runs there (stop it first)")
            self.path.unlink()  # left by a lab that was killed
        self.path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)  # the socket file is created 0600: only this user can connect
        try:
            sock.bind(str(self.path))
        finally:
            os.umask(old)
        sock.listen(8)
        self._sock = sock
        thread = threading.Thread(target=self._accept, name="twin-server", daemon=True)
        thread.start()
        self._threads.append(thread)
        return self

    def _accept(self) -> None:
        assert self._sock is not None
        while not self._closed.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return  # closed
            thread = threading.Thread(target=self._serve, args=(conn,), name="twin-client", daemon=True)
            thread.start()

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            conn.settimeout(REQUEST_TIMEOUT_S)
            try:
                request = read_line(conn)
            except (OSError, ValueError, ConnectionError) as exc:
                log.info("twin lab: a client left without a request (%s)", exc)
                return
            if request.get("v") != VERSION:
                with contextlib.suppress(OSError):
                    send_line(conn, {"ok": False, "error": f"protocol version {request.get('v')!r}, not {VERSION}"})
                return
            if request.get("want") == "camera":
                self._stream(conn, request.get("camera"))
                return
            reply = self._control(request)
            with contextlib.suppress(OSError):
                send_line(conn, reply)

    def _control(self, request: dict[str, Any]) -> dict[str, Any]:
        lab = self.lab
        try:
            what = request.get("do")
            if what == "scatter":
                return {"ok": True, "placed": lab.scatter()}
            camera = request.get("camera")
            if camera is not None and not isinstance(camera, str):
                return {"ok": False, "error": f"a camera is named by a string, not {camera!r}"}
            if what == "fault":
                seconds = float(request.get("seconds", 0))
                kind = str(request.get("kind"))
                return {"ok": True, "done": lab.fault(kind, seconds, request.get("rover"), camera)}
            if what == "note":
                lab.note(str(request.get("kind", "an edge fault")))
                return {"ok": True}
            if what == "status":
                return {"ok": True, **lab.status(int(request.get("after", 0)), camera)}
            if what == "wait":
                after = int(request.get("after", 0))
                timeout_s = min(float(request.get("seconds", 0.0)), MAX_WAIT_S)
                met = lab.wait_until(self._condition(request, after), timeout_s)
                return {"ok": True, "met": met, **lab.status(after, camera)}
            return {"ok": False, "error": f"unknown request {what!r}: scatter, fault, note, status or wait"}
        except (EdgeIpsError, TypeError, ValueError) as exc:
            return {"ok": False, "error": str(exc)}

    def _condition(self, request: dict[str, Any], after: int) -> Callable[[], bool]:
        """What a ``wait`` request waits for: ``event`` (one numbered after ``after``) or ``driving`` (a rover at
        ``speed_cm_s`` or faster by the ground truth)."""
        lab = self.lab
        if request.get("kind") == "event":
            return lambda: lab.events.count > after
        if request.get("kind") == "driving":
            speed_cm_s = float(request.get("speed_cm_s", "none"))  # ValueError when missing: refused
            return lambda: lab.fastest_cm_s() >= speed_cm_s
        raise ValueError(f"a wait is for an event or for driving, not {request.get('kind')!r}")

    def _stream(self, conn: socket.socket, name: object) -> None:
        try:
            if name is not None and not isinstance(name, str):
                raise SimulationError(f"a camera is named by a string, not {name!r}")
            _, camera = self.lab.camera_named(name)
            description = self.lab.describe(name)
        except EdgeIpsError as exc:
            with contextlib.suppress(OSError):
                send_line(conn, {"ok": False, "error": str(exc)})
            return
        slot = camera.attach()
        with self._lock:
            self._readers += 1
            self.last_reader_left = None
        try:
            conn.settimeout(SEND_TIMEOUT_S)
            send_line(conn, description.to_json())
            while not self._closed.is_set():
                frame = slot.take(timeout_s=0.5)
                if frame is None:
                    if slot.closed:
                        break
                    continue
                data = frame.image.tobytes()
                conn.sendall(frame_header(len(data), frame.index))
                conn.sendall(data)
        except OSError:
            pass  # the reader went away (an edge restarting, killed, or reopening its camera)
        finally:
            camera.detach(slot)
            with self._lock:
                self._readers -= 1
                if self._readers == 0:
                    self.last_reader_left = self.lab.clock()

    def close(self) -> None:
        self._closed.set()
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.shutdown(socket.SHUT_RDWR)
            self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
