"""The edge's side of the twin: ``--source sim:twin`` as a frame source, the lab's controls, starting the lab.

:class:`TwinSource` is a camera like any other to the appliance: it opens, hands over frames (stamped when they
arrive, as a USB camera's are), stalls when the lab's camera hangs (a read times out and the capture thread reopens
it), and closes. Like the other simulated sources it is an :class:`edge.sources.SimulatedScene`: it gives its
exact calibration (``exact_calibration()``, from the camera model the lab describes) and the rovers' marker colours
as its camera sees them (``rover_configs()``, for the tracker when none are configured); and it offers the lab's
controls (``controls``: scatter, faults), which the dashboard shows.

When no lab answers on the socket, the source starts one (``edge-ips sim twin`` as a child process, its output in
``twin.log`` beside the socket) with the rovers connecting to the edge's embedded broker with the state directory's
logins; it ends when the edge exits, or 30 s after the last camera reader left (an edge killed and not restarted).
With an external broker the lab is started by hand, with the rovers' logins for that broker.

A lab of several cameras (``edge-ips sim twin --cameras N``) is started by hand too, and each board opens its own
camera: ``--source sim:twin:cam2`` (plain ``sim:twin`` is the lab's first camera). Such a source never starts a
lab (the lab it would start has one camera), and its controls act on its own camera (``camera`` faults, the status'
``camera`` figures).
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import re
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge.errors import SimulationError, SourceError
from edge.sim.twin.wire import CameraDescription, ControlRequest, read_frame, read_line, send_line, socket_path
from edge.sources import SourceInfo
from edge.tracking import Frame

if TYPE_CHECKING:
    from edge.calibration import Calibration
    from edge.camera import PinholeCamera
    from edge.config import EdgeConfig
    from edge.tracker_config import RoverConfig

log = logging.getLogger("edge.sim.twin")

LAB_START_TIMEOUT_S = 180.0  # a lab measures its rovers' colours on rendered frames before it serves (slow when loaded)
UNWATCHED_EXIT_S = 30.0
_TARGET = re.compile(r"^twin(?::(cam[1-9]\d*))?$")


def parse_twin(target: str) -> str | None:
    """``twin`` -> None (the lab's first camera), ``twin:camK`` -> ``camK``; :class:`SourceError` otherwise."""
    match = _TARGET.match(target)
    if match is None:
        raise SourceError(f"sim:{target}: the live twin's cameras are sim:twin or sim:twin:camK (e.g. sim:twin:cam2)")
    return match[1]


class LabClient:
    """Control requests to the lab at ``path`` (one connection each); ``camera``: the camera a ``camera`` fault
    hangs and whose figures the status' ``camera`` holds (None: the lab's first, or the one ``fault`` names)."""

    def __init__(self, path: Path, timeout_s: float = 10.0, camera: str | None = None) -> None:
        self.path = path
        self.timeout_s = timeout_s
        self.camera = camera

    def request(self, req: ControlRequest, **extra: Any) -> dict[str, Any]:
        """The lab's reply; :class:`SimulationError` when the lab is not there or refuses."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(self.timeout_s)
            try:
                sock.connect(str(self.path))
                send_line(sock, {**req.to_json(), **extra})
                reply = read_line(sock)
            except (OSError, ValueError, ConnectionError) as exc:
                raise SimulationError(f"twin lab at {self.path}: {exc}") from None
        if not reply.get("ok"):
            raise SimulationError(str(reply.get("error", "refused")))
        return reply

    def scatter(self) -> dict[str, Any]:
        return dict(self.request(ControlRequest("scatter"))["placed"])

    def fault(self, kind: str, seconds: float, rover: str | None = None, camera: str | None = None) -> str:
        camera = camera or (self.camera if kind == "camera" else None)
        request = ControlRequest("fault", kind=kind, rover=rover, seconds=seconds, camera=camera)
        return str(self.request(request)["done"])

    def note(self, label: str) -> None:
        self.request(ControlRequest("note", kind=label))

    def status(self, after: int = 0) -> dict[str, Any]:
        return self.request(ControlRequest("status", camera=self.camera), after=after)

    def wait_event(self, after: int, timeout_s: float) -> dict[str, Any]:
        """The status (events after ``after``) once the lab has an event numbered after ``after``, or at
        ``timeout_s`` (``met`` says which)."""
        return self._wait(
            ControlRequest("wait", kind="event", seconds=timeout_s, camera=self.camera), timeout_s, after=after
        )

    def wait_driving(self, speed_cm_s: float, timeout_s: float) -> dict[str, Any]:
        """The status once a rover drives at ``speed_cm_s`` or faster by the ground truth, or at ``timeout_s``."""
        request = ControlRequest("wait", kind="driving", seconds=timeout_s, camera=self.camera)
        return self._wait(request, timeout_s, speed_cm_s=speed_cm_s)

    def _wait(self, req: ControlRequest, timeout_s: float, **extra: Any) -> dict[str, Any]:
        waiting = LabClient(self.path, self.timeout_s + timeout_s, self.camera)  # the reply comes when it is met
        return waiting.request(req, **extra)


@dataclass
class LabLaunch:
    """How to start a lab when none answers: ``argv`` (after ``python -m edge.cli``), its log file."""

    argv: list[str]
    log_path: Path
    process: subprocess.Popen[bytes] | None = None

    def ensure(self) -> None:
        """Start the lab unless the one started before still runs."""
        if self.process is not None and self.process.poll() is None:
            return
        self.log_path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        with self.log_path.open("ab") as out:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "edge.cli", *self.argv], stdin=subprocess.DEVNULL, stdout=out, stderr=out
            )
        atexit.register(self.stop)  # a clean exit of the edge ends its lab; a killed edge's lab ends unwatched
        log.info("twin lab started (pid %d): %s; its log: %s", self.process.pid, " ".join(self.argv), self.log_path)

    @property
    def exited(self) -> int | None:
        return None if self.process is None else self.process.poll()

    def stop(self, timeout_s: float = 10.0) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


class TwinSource:
    """The twin lab's camera ``camera`` (None: its first) at the Unix socket ``path`` (see the module docstring).
    ``read_timeout_s``: a read that waits longer fails (the capture thread then reopens the source with backoff)."""

    def __init__(
        self,
        path: Path,
        *,
        camera: str | None = None,
        launch: LabLaunch | None = None,
        read_timeout_s: float = 4.0,
    ) -> None:
        self.path = path
        self.camera_name = camera
        self.launch = launch
        self.read_timeout_s = read_timeout_s
        self.controls = LabClient(path, camera=camera)
        self._sock: socket.socket | None = None
        self._description: CameraDescription | None = None

    # -- FrameSource ----------------------------------------------------------------------------------------------
    def open(self) -> SourceInfo:
        sock = self._connect()
        try:
            sock.settimeout(self.read_timeout_s)
            request: dict[str, Any] = {"v": 1, "want": "camera"}
            if self.camera_name is not None:
                request["camera"] = self.camera_name
            send_line(sock, request)
            reply = read_line(sock)
        except (OSError, ValueError, ConnectionError) as exc:
            sock.close()
            raise SourceError(f"twin lab at {self.path}: {exc}") from None
        if reply.get("ok") is False:
            sock.close()
            raise SourceError(f"twin lab at {self.path}: {reply.get('error', 'refused')}")
        try:
            description = CameraDescription.from_json(reply)
        except SourceError:
            sock.close()
            raise
        self._sock, self._description = sock, description
        d = description
        spec = "sim:twin" if self.camera_name is None else f"sim:twin:{self.camera_name}"
        # the lab renders without compression and sends the frames as they are: no chroma spread (edge_offsets auto)
        return SourceInfo(
            d.width_px, d.height_px, d.fps, f"{spec}, {d.summary} (socket {self.path})", chroma_spread=False
        )

    def _connect(self) -> socket.socket:
        sock = _dial(self.path)
        if sock is not None:
            return sock
        if self.launch is None:
            cameras = "" if self.camera_name is None else " --cameras N"
            raise SourceError(
                f"no twin lab answers at {self.path}: start one with `edge-ips sim twin{cameras}` (with --broker and "
                "the rovers' --credentials of your broker)"
            )
        self.launch.ensure()
        deadline = time.monotonic() + LAB_START_TIMEOUT_S
        while (sock := _dial(self.path)) is None:
            code = self.launch.exited
            if code is not None:
                raise SourceError(f"the twin lab exited with code {code} before serving; see {self.launch.log_path}")
            if time.monotonic() > deadline:
                raise SourceError(f"the twin lab did not serve within {LAB_START_TIMEOUT_S:g} s")
            time.sleep(0.2)  # the child is rendering its first frames: poll its socket
        return sock

    def read(self) -> Frame | None:
        if self._sock is None or self._description is None:
            raise SourceError("twin source: read() before open()")
        try:
            number, image = read_frame(self._sock, self._description.width_px, self._description.height_px)
        except TimeoutError:
            raise SourceError(f"twin lab: no frame for {self.read_timeout_s:g} s (the camera hangs)") from None
        except (OSError, ConnectionError) as exc:
            raise SourceError(f"twin lab: camera stream lost ({exc})") from None
        return Frame(image=image, index=number, t_capture_s=time.time(), t_mono_s=time.monotonic())

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None

    # -- what a simulated source tells the appliance ----------------------------------------------------------------
    @property
    def camera(self) -> PinholeCamera:
        """The lab camera's exact model (after :meth:`open`)."""
        if self._description is None:
            raise SourceError("twin source: the camera is known once the source is open")
        return self._description.camera

    def exact_calibration(self) -> Calibration:
        """The exact calibration of the lab's camera on the marker plane (a simulated camera knows its model)."""
        from edge.calibration.exact import exact_calibration

        return exact_calibration(self.camera)

    def rover_configs(self) -> tuple[RoverConfig, ...]:
        """The lab's rovers: ids, marker colours as its camera sees them (after :meth:`open`)."""
        if self._description is None:
            raise SourceError("twin source: the rovers are known once the source is open")
        return self._description.rovers


def _dial(path: Path) -> socket.socket | None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(5.0)
    try:
        sock.connect(str(path))
    except OSError:
        sock.close()
        return None
    return sock


def twin_source(config: EdgeConfig, target: str = "twin") -> TwinSource:
    """The source for ``--source sim:twin[:camK]`` (``target``: what follows ``sim:``): camera K (the first when
    none is named) of the lab at the state directory's socket; for the first camera on the embedded broker, a lab
    started when none answers (see the module docstring)."""
    from edge.config import broker_target, state_dir
    from edge.errors import ConfigError

    camera = parse_twin(target)
    directory = state_dir(config)
    path = socket_path(directory)
    read_timeout_s = max(2.0 * config.camera.stall_timeout_s, 2.0)
    if camera is not None or not broker_target(config.broker).embedded:
        return TwinSource(path, camera=camera, read_timeout_s=read_timeout_s)
    from edge.broker.credentials import credentials_path

    port = config.broker.embedded_port
    if port == 0:
        raise ConfigError("sim:twin starts its rovers on the embedded broker's port: set broker.embedded_port (not 0)")
    host = config.broker.embedded_host
    host = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    argv = [
        "sim",
        "twin",
        "--socket",
        str(path),
        "--broker",
        f"mqtt://{host}:{port}",
        "--credentials",
        str(credentials_path(directory)),
        "--wait-for-logins",
        "--exit-unwatched",
        f"{UNWATCHED_EXIT_S:g}",
    ]
    return TwinSource(path, launch=LabLaunch(argv, directory / "twin.log"), read_timeout_s=read_timeout_s)
