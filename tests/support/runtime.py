"""Helpers for the runtime's tests: a tiny colour-centroid tracker, synthetic frames, an MQTT recorder, an MJPEG
stream server that can stall or vanish. Real parts everywhere except the tracker: a fake of the ``Tracker``
protocol (STYLE point 3), so the runtime's tests do not depend on the vision.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import paho.mqtt.client as mqtt
from numpy.typing import NDArray

from edge.tracker_config import DEFAULT_ROVERS, RoverConfig
from edge.tracking import Frame, FrameResult, RoverEstimate

CM_PER_PX = 1.0  # the fake tracker's whole calibration: one pixel is one centimetre


class CentroidTracker:
    """Finds each rover as the centroid of the pixels near its marker colour: enough to check the plumbing."""

    def __init__(self, rovers: Sequence[RoverConfig] = DEFAULT_ROVERS, tolerance: int = 30, stride: int = 1) -> None:
        self.rovers = tuple(rovers)
        self.tolerance = tolerance
        self.stride = stride  # look at every stride-th pixel only: cheap on large frames (benchmarks)
        self.calls = 0

    def process(self, frame: Frame) -> FrameResult:
        self.calls += 1
        s = self.stride
        img = frame.image[::s, ::s].astype(np.int16)
        estimates, missing = [], []
        for rover in self.rovers:
            mask = np.all(np.abs(img - np.array(rover.color_bgr, dtype=np.int16)) < self.tolerance, axis=2)
            vs, us = np.nonzero(mask)
            if us.size < 5:
                missing.append(rover.id)
                continue
            u, v = float(us.mean()) * s, float(vs.mean()) * s
            estimates.append(RoverEstimate(rover.id, u * CM_PER_PX, v * CM_PER_PX, 0.0, None, None, 1.0, (u, v)))
        return FrameResult(frame.index, frame.t_capture_s, frame.t_mono_s, tuple(estimates), tuple(missing), {})

    def reset(self) -> None:
        pass  # keeps nothing from frame to frame

    def close(self) -> None:
        pass


def scene(
    index: int, width: int = 320, height: int = 240, rovers: Sequence[RoverConfig] = DEFAULT_ROVERS
) -> NDArray[np.uint8]:
    """A grey floor with one filled disc per rover, moving one pixel per frame along x (scaled to the size)."""
    img = np.full((height, width, 3), 90, dtype=np.uint8)
    k_px = width / 320
    for k, rover in enumerate(rovers):
        u = int(k_px * (30 + (index + 40 * k) % 260))
        v = int(k_px * (40 + 60 * k))
        cv2.circle(img, (u, v), int(10 * k_px), tuple(int(c) for c in rover.color_bgr), -1)
    return img


def write_clip(path: Path, frames: int = 60, fps: float = 30.0, width: int = 320, height: int = 240) -> Path:
    """An MJPG AVI of :func:`scene` frames."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, (width, height))
    for i in range(frames):
        writer.write(scene(i, width, height))
    writer.release()
    return path


@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool
    t_recv: float
    qos: int = 0


@dataclass
class MqttRecorder:
    """A paho subscriber that keeps everything it receives (with arrival time) and can wait for a condition."""

    host: str
    port: int
    topics: Sequence[str] = ("ips/v1/#",)
    username: str | None = None
    password: str | None = None
    messages: list[Received] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._cond = threading.Condition()
        self.subscribed = threading.Event()  # set when the broker acknowledged the subscriptions (each connection)
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="")
        if self.username:
            self.client.username_pw_set(self.username, self.password)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.on_subscribe = lambda *args: self.subscribed.set()
        self.client.reconnect_delay_set(0.1, 0.5)

    def _on_connect(self, c: Any, u: Any, flags: Any, rc: Any, props: Any) -> None:
        self.subscribed.clear()
        c.subscribe([(t, 1) for t in self.topics])

    def _on_message(self, c: Any, u: Any, msg: mqtt.MQTTMessage) -> None:
        with self._cond:
            self.messages.append(Received(msg.topic, bytes(msg.payload), bool(msg.retain), time.time(), msg.qos))
            self._cond.notify_all()

    def start(self) -> MqttRecorder:
        self.client.connect_async(self.host, self.port, keepalive=5)
        self.client.loop_start()
        return self

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> MqttRecorder:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait_subscribed(self, timeout_s: float = 20.0) -> bool:
        """Wait until the broker has acknowledged the subscriptions: from then on nothing published is missed."""
        return self.subscribed.wait(timeout_s)

    def wait_for(self, predicate: Callable[[list[Received]], bool], timeout_s: float = 20.0) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: predicate(self.messages), timeout=timeout_s)

    def on(self, topic_part: str) -> list[Received]:
        with self._cond:
            return [m for m in self.messages if topic_part in m.topic]

    def json_on(self, topic_part: str) -> list[dict[str, Any]]:
        return [json.loads(m.payload) for m in self.on(topic_part)]


def poses(messages: list[Received]) -> list[Received]:
    return [m for m in messages if m.topic.endswith("/pose")]


def statuses(messages: list[Received]) -> list[dict[str, Any]]:
    return [json.loads(m.payload) for m in messages if m.topic.startswith("ips/v1/edge/")]


class Switch:
    """An on/off a test flips (``set``/``clear``, as :class:`threading.Event`) and a thread can wait to see off."""

    def __init__(self) -> None:
        self._on = False
        self._changed = threading.Condition()

    def set(self) -> None:
        with self._changed:
            self._on = True
            self._changed.notify_all()

    def clear(self) -> None:
        with self._changed:
            self._on = False
            self._changed.notify_all()

    def is_set(self) -> bool:
        return self._on

    def wait_off(self, stop: threading.Event, timeout_s: float = 1.0) -> None:
        """Until off, or up to ``timeout_s`` (the caller checks ``stop`` then: a stopped server does not wait)."""
        with self._changed:
            self._changed.wait_for(lambda: not self._on or stop.is_set(), timeout_s)


class MjpegServer:
    """An HTTP multipart-JPEG stream of :func:`scene` frames at ``fps`` that a test can stall, kill and revive
    (at another ``size`` if it likes); ``requests`` counts the connections it answered."""

    def __init__(self, fps: float = 30.0, port: int = 0, size: tuple[int, int] = (320, 240)) -> None:
        self.fps = fps
        self.size = size
        self.requests = 0
        self._answered = threading.Condition()
        self.stalled = Switch()  # set: the connection stays open, no frames
        self._port = port
        self._server: ThreadingHTTPServer | None = None
        self._stop = threading.Event()
        self.frames_sent = 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self._port}/stream.mjpg"

    def _handler(self) -> type[BaseHTTPRequestHandler]:
        owner = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                with owner._answered:
                    owner.requests += 1
                    owner._answered.notify_all()
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
                self.end_headers()
                i = 0
                try:
                    while not owner._stop.is_set():
                        if owner.stalled.is_set():
                            owner.stalled.wait_off(owner._stop)
                            continue
                        _, jpg = cv2.imencode(".jpg", scene(i, *owner.size))
                        data = jpg.tobytes()
                        self.wfile.write(
                            b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n" % len(data)
                            + data
                            + b"\r\n"
                        )
                        owner.frames_sent += 1
                        i += 1
                        owner._stop.wait(1.0 / owner.fps)  # the camera's frame period
                except (BrokenPipeError, ConnectionResetError):
                    pass

            def log_message(self, format: str, *args: object) -> None:
                pass

        return Handler

    def wait_requests(self, n: int, timeout_s: float = 30.0) -> bool:
        with self._answered:
            return self._answered.wait_for(lambda: self.requests >= n, timeout_s)

    def start(self) -> MjpegServer:
        self._stop.clear()
        server = ThreadingHTTPServer(("127.0.0.1", self._port), self._handler())
        server.daemon_threads = True
        self._port = int(server.server_address[1])
        self._server = server
        threading.Thread(target=server.serve_forever, daemon=True).start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None


def make_tls_files(directory: Path, name: str = "ca") -> dict[str, Path]:
    """A throw-away CA and a server certificate for ``localhost``/127.0.0.1, made with the openssl CLI."""
    import subprocess

    directory.mkdir(parents=True, exist_ok=True)
    ca_key, ca_crt = directory / f"{name}.key", directory / f"{name}.crt"
    key, csr, crt = directory / "server.key", directory / "server.csr", directory / "server.crt"
    ext = directory / "san.ext"
    ext.write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], check=True, capture_output=True)

    run(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-days",
        "2",
        "-subj",
        f"/CN={name}",
        "-keyout",
        str(ca_key),
        "-out",
        str(ca_crt),
    )
    run("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=localhost", "-keyout", str(key), "-out", str(csr))
    run(
        "x509",
        "-req",
        "-in",
        str(csr),
        "-CA",
        str(ca_crt),
        "-CAkey",
        str(ca_key),
        "-CAcreateserial",
        "-days",
        "2",
        "-extfile",
        str(ext),
        "-out",
        str(crt),
    )
    for path in (ca_key, key):
        path.chmod(0o644)  # mosquitto drops privileges before reading them
    return {"ca": ca_crt, "cert": crt, "key": key}


def stop_process(proc: subprocess.Popen[Any], timeout_s: float = 30.0) -> None:
    """Stop a process the way systemd would: SIGTERM, then SIGKILL if it has not exited within ``timeout_s``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
