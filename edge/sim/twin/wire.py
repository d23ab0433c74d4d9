"""What the twin's lab and the appliance say to each other over the lab's local socket, both ways, in one place.

The lab (``edge-ips sim twin``) listens on a Unix stream socket (``twin.sock`` in the state directory: only its
owner can connect). A client opens a connection and sends one request line (JSON, at most
:data:`MAX_LINE_BYTES`):

* ``{"v": 1, "want": "camera", "camera": "cam2"}``: the lab answers one line describing that camera
  (:class:`CameraDescription`: its name, image size, frame rate, the camera model in the floor's frame, the floor
  region it watches, each rover's id and marker colours as the camera sees them), then frames until either side
  closes (no ``camera``: the lab's first; a name the lab has not: one line ``{"ok": false, "error": ...}``):
  a :data:`FRAME_HEADER` (magic, payload length, the camera's frame number) and the image as raw 8-bit BGR rows.
  A camera hands over pictures, nothing else: no world state, no timestamps (the reader stamps a frame when it has
  it, as with a USB camera).
* ``{"v": 1, "want": "control", ...}``: one :class:`ControlRequest`, one JSON reply line, then the lab closes.
"""

from __future__ import annotations

import json
import socket
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge.camera import PinholeCamera
from edge.errors import ConfigError, SourceError
from edge.tracker_config import RoverConfig

VERSION = 1
MAX_LINE_BYTES = 65536
FRAME_MAGIC = b"TWF1"
FRAME_HEADER = struct.Struct("<4sIQ")  # magic, payload bytes, frame number
SOCKET_NAME = "twin.sock"
_MAX_SOCKET_PATH = 107  # sun_path holds 108 bytes with the terminating zero

FAULT_KINDS = ("wifi", "camera", "broker", "edge")  # wifi and camera happen in the lab; broker and edge at the edge
LAB_FAULTS = ("wifi", "camera")


def socket_path(state_dir: Path) -> Path:
    """The lab's socket in a state directory; :class:`ConfigError` when the path is too long for a Unix socket."""
    path = state_dir / SOCKET_NAME
    if len(str(path).encode()) > _MAX_SOCKET_PATH:
        raise ConfigError(
            f"{path}: too long for a Unix socket ({len(str(path))} bytes, at most {_MAX_SOCKET_PATH}); "
            "set edge.state_dir to a shorter directory"
        )
    return path


@dataclass(frozen=True)
class CameraDescription:
    """What a camera client learns when it connects: the picture's size and rate, the camera model (the exact
    calibration of a simulated camera, in the floor frame every camera of the lab shares), and the rovers as this
    camera sees them (for the tracker's settings); ``name`` and ``region_cm`` (x0, y0, x1, y1) say which camera."""

    width_px: int
    height_px: int
    fps: float
    camera: PinholeCamera
    rovers: tuple[RoverConfig, ...]
    summary: str
    name: str = "cam1"
    region_cm: tuple[float, float, float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        c = self.camera
        return {
            "v": VERSION,
            "width": self.width_px,
            "height": self.height_px,
            "fps": self.fps,
            "camera": {
                "camera_matrix": c.camera_matrix.tolist(),
                "dist_coeffs": c.dist_coeffs.tolist(),
                "rvec": c.rvec.tolist(),
                "tvec": c.tvec.tolist(),
            },
            "rovers": [r.model_dump(mode="json") for r in self.rovers],
            "summary": self.summary,
            "name": self.name,
            "region_cm": None if self.region_cm is None else list(self.region_cm),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> CameraDescription:
        try:
            c = data["camera"]
            width, height = int(data["width"]), int(data["height"])
            camera = PinholeCamera(
                np.array(c["camera_matrix"], dtype=np.float64),
                np.array(c["dist_coeffs"], dtype=np.float64),
                np.array(c["rvec"], dtype=np.float64),
                np.array(c["tvec"], dtype=np.float64),
                width,
                height,
            )
            rovers = tuple(RoverConfig.model_validate(r) for r in data["rovers"])
            region_cm = None
            if data.get("region_cm") is not None:
                x0, y0, x1, y1 = (float(v) for v in data["region_cm"])
                region_cm = (x0, y0, x1, y1)
            return cls(
                width,
                height,
                float(data["fps"]),
                camera,
                rovers,
                str(data.get("summary", "")),
                name=str(data.get("name", "cam1")),
                region_cm=region_cm,
            )
        except Exception as exc:  # a lab of another version, or not a lab at all
            raise SourceError(f"twin lab: a camera description this edge cannot read ({exc})") from None


@dataclass(frozen=True)
class ControlRequest:
    """``scatter``, ``fault`` (``kind`` one of :data:`FAULT_KINDS`, ``rover`` for wifi, ``camera`` for camera: the
    lab's first when None; ``seconds``), ``note`` (an edge-side fault about to happen: the lab times how fast the
    rovers stop), ``status`` (``camera``: whose figures ``camera`` holds; ``cameras`` lists all) or ``wait`` (``kind``
    ``event`` or ``driving``, at most ``seconds``: the status once it came, ``met`` false if it did not)."""

    do: str
    kind: str | None = None
    rover: str | None = None
    seconds: float | None = None
    camera: str | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"v": VERSION, "want": "control", "do": self.do}
        for key in ("kind", "rover", "seconds", "camera"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        return out


def send_line(sock: socket.socket, data: dict[str, Any]) -> None:
    sock.sendall(json.dumps(data, separators=(",", ":")).encode() + b"\n")


def read_line(sock: socket.socket) -> dict[str, Any]:
    """One JSON line (a byte at a time would be slow for frames, but lines come only before them)."""
    buf = bytearray()
    while not buf.endswith(b"\n"):
        chunk = sock.recv(1)
        if not chunk:
            raise ConnectionError("closed before a whole line arrived")
        buf += chunk
        if len(buf) > MAX_LINE_BYTES:
            raise ValueError(f"a line longer than {MAX_LINE_BYTES} bytes")
    data = json.loads(buf)
    if not isinstance(data, dict):
        raise ValueError("expected a JSON object")
    return data


def frame_header(nbytes: int, number: int) -> bytes:
    return FRAME_HEADER.pack(FRAME_MAGIC, nbytes, number)


def read_exact(sock: socket.socket, n: int) -> bytearray:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = sock.recv_into(view[got:], n - got)
        if k == 0:
            raise ConnectionError("the lab closed the camera stream")
        got += k
    return buf


def read_frame(sock: socket.socket, width_px: int, height_px: int) -> tuple[int, NDArray[np.uint8]]:
    """(frame number, (H, W, 3) uint8 BGR image) of the next frame; :class:`SourceError` on a broken stream."""
    magic, nbytes, number = FRAME_HEADER.unpack(read_exact(sock, FRAME_HEADER.size))
    if magic != FRAME_MAGIC or nbytes != width_px * height_px * 3:
        raise SourceError(f"twin lab: a frame header this edge cannot read ({magic!r}, {nbytes} bytes)")
    image = np.frombuffer(read_exact(sock, nbytes), dtype=np.uint8).reshape(height_px, width_px, 3)
    return int(number), image
