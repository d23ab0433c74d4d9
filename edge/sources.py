"""Frame sources: where frames come from (V4L2 camera, video file, RTSP/HTTP stream, simulator).

Every source yields :class:`Frame` objects through the small :class:`FrameSource` protocol. The capture timestamp
is taken at grab (``time.time()`` for the wire, ``time.monotonic()`` for latency) and travels with the frame into
the pose message's ``t``.

Live capture (the newest-frame slot and the thread that reopens a vanished source) is in :mod:`edge.capture`.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from edge.camera_controls import (
    CameraControls,
    ControlDevice,
    ControlError,
    ControlsReport,
    apply_controls,
    automatic_modes_on,
    sharpening_on,
)
from edge.clock import SYSTEM_CLOCK, Clock
from edge.errors import SourceError
from edge.tracking import Frame

if TYPE_CHECKING:
    from edge.calibration import Calibration
    from edge.tracker_config import RoverConfig

log = logging.getLogger("edge.sources")


@dataclass(frozen=True)
class SourceInfo:
    """What a source really delivers (a camera may grant less than was requested)."""

    width_px: int
    height_px: int
    fps: float
    description: str
    # the frames came through a colour path that spreads the chroma: a camera's (demosaicing, 4:2:2 or 4:2:0
    # sampling, JPEG) or a codec's; what the ``edge_offsets`` tracker setting's ``auto`` follows
    chroma_spread: bool = True
    # the camera may sharpen its luma: False only where its sharpening is known to be off (a camera whose sharpness
    # control was read back at its least); what ``TrackerConfig.camera_sharpens`` follows
    sharpened: bool = True


@runtime_checkable
class FrameSource(Protocol):
    """A source of frames. ``open`` before ``read``; ``read`` returns None at the end of a finite stream."""

    def open(self) -> SourceInfo: ...

    def read(self) -> Frame | None: ...

    def close(self) -> None: ...


@runtime_checkable
class SimulatedScene(Protocol):
    """What a simulated camera knows that a real one does not, for the appliance (optional: check with
    ``isinstance``): its exact calibration, and its rovers' ids and marker colours as it renders them."""

    def exact_calibration(self) -> Calibration: ...

    def rover_configs(self) -> tuple[RoverConfig, ...]: ...


# -- OpenCV-backed sources ---------------------------------------------------------------------------------------
class _OpenCvSource:
    """Shared grab/retrieve logic: the timestamp is taken when the frame is dequeued, before it is decoded."""

    def __init__(self) -> None:
        self._cap: Any = None
        self._index = 0

    def _grab(self, what: str) -> Frame | None:
        """The next frame, or None when the backend has none (end of file, device gone, stalled stream)."""
        import cv2

        if self._cap is None:
            raise SourceError(f"{what}: read before open")
        try:
            if not self._cap.grab():
                return None
            t_capture_s, t_mono_s = time.time(), time.monotonic()
            ok, image = self._cap.retrieve()
        except cv2.error as exc:
            raise SourceError(f"{what}: {exc}") from exc
        if not ok or image is None:
            raise SourceError(f"{what}: frame could not be decoded")
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        frame = Frame(image=image, index=self._index, t_capture_s=t_capture_s, t_mono_s=t_mono_s)
        self._index += 1
        return frame

    def _grab_live(self, what: str) -> Frame:
        frame = self._grab(what)
        if frame is None:
            raise SourceError(f"{what}: no frame (device gone or stream stalled)")
        return frame

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def _fourcc_text(code: float) -> str:
    value = int(code)
    text = "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4))
    return text if text.isprintable() and text.strip() else f"0x{value:08x}"


def _v4l2_capture(path: str) -> Any:
    import cv2

    return cv2.VideoCapture(path, cv2.CAP_V4L2)


def _v4l2_controls(path: str) -> ControlDevice:
    from edge.v4l2 import V4l2Controls

    return V4l2Controls(path)


class CameraSource(_OpenCvSource):
    """A V4L2 camera by index (``0``) or device path (``/dev/video0``).

    Asks for ``width`` x ``height`` at ``fps`` in ``fourcc`` (MJPG: a USB 2.0 webcam such as the paper's C920
    only reaches 1280x720 at 30 fps compressed) and reports what the driver granted. With ``controls`` (focus,
    white balance, exposure...) it sets them at every open, so a camera that was unplugged (and lost them) gets
    them back on the reopen, and logs what the camera granted. They are set once the stream runs (after the first
    frame): some UVC cameras reset focus and exposure when streaming starts.

    ``open_capture`` and ``open_controls`` build the OpenCV capture and the control device from the path (tests
    give stand-ins; a real camera needs neither).
    """

    def __init__(
        self,
        device: int | str,
        *,
        width: int = 1280,
        height: int = 720,
        fps: float = 30.0,
        fourcc: str = "MJPG",
        controls: CameraControls | None = None,
        open_capture: Callable[[str], Any] = _v4l2_capture,
        open_controls: Callable[[str], ControlDevice] = _v4l2_controls,
    ) -> None:
        super().__init__()
        self.device = device
        self.width, self.height, self.fps, self.fourcc = width, height, fps, fourcc
        self.controls = controls or CameraControls()
        self.controls_report = ControlsReport()
        self._open_capture, self._open_controls = open_capture, open_controls

    @property
    def path(self) -> str:
        return f"/dev/video{self.device}" if isinstance(self.device, int) else str(self.device)

    def open(self) -> SourceInfo:
        import cv2

        if not Path(self.path).exists():
            raise SourceError(f"no camera at {self.path} (is it plugged in? without a camera use --source sim)")
        cap = self._open_capture(self.path)
        if not cap.isOpened():
            cap.release()
            raise SourceError(f"camera {self.path} exists but cannot be opened (in use, or no permission: video group)")
        # Order matters for V4L2: the pixel format decides which sizes and rates exist.
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        self._cap = cap
        granted_w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        granted_h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        granted_fps = float(cap.get(cv2.CAP_PROP_FPS)) or self.fps
        granted_fourcc = _fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        asked = f"{self.width}x{self.height}@{self.fps:g} {self.fourcc}"
        granted = f"{granted_w}x{granted_h}@{granted_fps:g} {granted_fourcc}"
        note = "" if asked == granted else f" (asked {asked})"
        self._sharpened = True  # not known: a camera's sharpening is read back with its controls
        if self.controls.wanted():
            self._apply_controls()
        description = f"camera {self.path}: {granted}{note}"
        return SourceInfo(granted_w, granted_h, granted_fps, description, sharpened=self._sharpened)

    def _apply_controls(self) -> None:
        if not self._cap.grab():  # starts the stream: controls set before it may be reset by it
            self.close()
            raise SourceError(f"camera {self.path} opened but delivers no frame")
        try:
            device = self._open_controls(self.path)
        except ControlError as exc:
            self.controls_report = ControlsReport()
            log.warning("camera %s: controls not set: %s", self.path, exc)
            return
        try:
            self.controls_report = apply_controls(device, self.controls)
            self._sharpened = device.query("sharpness") is None or sharpening_on(device) is not None
        except ControlError as exc:  # the camera went away while being set up
            self.close()
            raise SourceError(f"camera {self.path}: {exc}") from exc
        finally:
            device.close()
        level = logging.INFO if self.controls_report.ok else logging.WARNING
        log.log(level, "camera %s controls granted: %s", self.path, self.controls_report.line())

    def automatic_modes(self) -> list[str]:
        """The automatic modes that move a calibration or the colours (autofocus, auto white balance) on now."""
        device = self._open_controls(self.path)
        try:
            return automatic_modes_on(device)
        finally:
            device.close()

    def sharpening(self) -> str | None:
        """The camera's sharpening when it is on (:func:`edge.camera_controls.sharpening_on`), else None."""
        device = self._open_controls(self.path)
        try:
            return sharpening_on(device)
        finally:
            device.close()

    def read(self) -> Frame | None:
        return self._grab_live(f"camera {self.path}")


class VideoFileSource(_OpenCvSource):
    """A video file, optionally looping; with ``realtime`` frames are delivered at the file's frame rate."""

    def __init__(self, path: Path, *, loop: bool = False, realtime: bool = True, fps: float | None = None) -> None:
        super().__init__()
        self.path = Path(path)
        self.loop = loop
        self.realtime = realtime
        self._fps_override = fps
        self._period_s = 0.0
        self._next_due = 0.0

    def open(self) -> SourceInfo:
        import cv2

        if not self.path.is_file():
            raise SourceError(f"{self.path}: video file not found")
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            cap.release()
            raise SourceError(f"{self.path}: not a video file OpenCV can read")
        self._cap = cap
        fps = self._fps_override or float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
        self._period_s = 1.0 / fps
        self._next_due = time.monotonic()
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        mode = ", looping" if self.loop else ""
        return SourceInfo(w, h, fps, f"video file {self.path}: {w}x{h}@{fps:g}{mode}")

    def read(self) -> Frame | None:
        import cv2

        if self.realtime:
            now = time.monotonic()
            if self._next_due > now:
                time.sleep(self._next_due - now)
            # A slow reader does not build up a debt of frames to rush through.
            self._next_due = max(self._next_due, now - self._period_s) + self._period_s
        what = f"video file {self.path}"
        frame = self._grab(what)
        if frame is None and self.loop:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            frame = self._grab(what)
            if frame is None:
                raise SourceError(f"{what}: cannot start again from the beginning")
        return frame


class StreamSource(_OpenCvSource):
    """An RTSP or HTTP(S) stream (MJPEG over HTTP, H.264 over RTSP...) read with FFmpeg.

    ``read_timeout_s`` bounds a stalled read: it then fails and the capture thread reopens the stream.
    """

    def __init__(self, url: str, *, open_timeout_s: float = 5.0, read_timeout_s: float = 2.0) -> None:
        super().__init__()
        self.url = url
        self.open_timeout_s, self.read_timeout_s = open_timeout_s, read_timeout_s

    @property
    def shown_url(self) -> str:
        return re.sub(r"//[^/@]*@", "//***@", self.url)  # never log stream credentials

    def open(self) -> SourceInfo:
        import cv2

        params = [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
            int(self.open_timeout_s * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC,
            int(self.read_timeout_s * 1000),
        ]
        cap = cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, params)
        if not cap.isOpened():
            cap.release()
            raise SourceError(f"stream {self.shown_url}: cannot be opened (unreachable, or not a video stream)")
        self._cap = cap
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
        return SourceInfo(w, h, fps, f"stream {self.shown_url}: {w}x{h}@{fps:g}")

    def read(self) -> Frame | None:
        return self._grab_live(f"stream {self.shown_url}")


class MemorySource:
    """Frames from memory, in order, optionally paced at ``fps`` (in real time): for tests and pre-rendered clips.
    Frames are stamped by ``clock``; ``chroma_spread``: whether they came through a camera's or a codec's colour
    path (:class:`SourceInfo`)."""

    def __init__(
        self,
        images: Sequence[NDArray[np.uint8]],
        *,
        fps: float = 30.0,
        loop: bool = False,
        realtime: bool = False,
        clock: Clock = SYSTEM_CLOCK,
        chroma_spread: bool = True,
    ) -> None:
        if not images:
            raise SourceError("memory source: no frames")
        self.images = images
        self.chroma_spread = chroma_spread
        self.fps, self.loop, self.realtime = fps, loop, realtime
        self.clock = clock
        self._index = 0
        self._next_due = 0.0

    def open(self) -> SourceInfo:
        h, w = self.images[0].shape[:2]
        self._next_due = time.monotonic()
        return SourceInfo(
            w, h, self.fps, f"memory: {len(self.images)} frames {w}x{h}@{self.fps:g}", chroma_spread=self.chroma_spread
        )

    def read(self) -> Frame | None:
        if self._index >= len(self.images) and not self.loop:
            return None
        if self.realtime:
            now = time.monotonic()
            if self._next_due > now:
                time.sleep(self._next_due - now)
            self._next_due = max(self._next_due, now - 1.0 / self.fps) + 1.0 / self.fps
        image = self.images[self._index % len(self.images)]
        frame = Frame(image=image, index=self._index, t_capture_s=self.clock.wall(), t_mono_s=self.clock.monotonic())
        self._index += 1
        return frame

    def close(self) -> None:
        pass


# -- reading a few frames ---------------------------------------------------------------------------------------
def grab_frame(source: FrameSource, settle_frames: int = 10) -> NDArray[np.uint8]:
    """One frame of a live ``source``: the last of its first ``settle_frames`` (:func:`grab_frames`)."""
    return grab_frames(source, 1, settle_frames - 1)[0]


def grab_frames(source: FrameSource, count: int, settle_frames: int = 9) -> list[NDArray[np.uint8]]:
    """``count`` consecutive frames of a live ``source`` after its first ``settle_frames`` (a camera's first frames
    come before its exposure has settled); fewer if it ends first, at least the last it gave. Opens, closes it."""
    source.open()
    images: list[NDArray[np.uint8]] = []
    try:
        for i in range(settle_frames + count):
            if (frame := source.read()) is None:
                break
            images = [*images, frame.image] if i > settle_frames else [frame.image]  # settling frames not kept
    finally:
        source.close()
    if not images:
        raise SourceError("the source delivered no frame")
    return images
