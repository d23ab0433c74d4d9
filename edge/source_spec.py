"""Choosing a source: the text that names one (``--source``, ``[camera] source``) and the source it builds.

``0`` or ``/dev/...`` is a V4L2 camera, ``rtsp://`` or ``http(s)://`` a stream, ``sim[:SCENARIO]`` the simulator
(built by a :class:`SimFactory` the appliance hands in, so this module does not reach the simulator), anything else a
video file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from edge.errors import SourceError
from edge.sources import CameraSource, FrameSource, StreamSource, VideoFileSource

if TYPE_CHECKING:
    from edge.camera_controls import CameraControls
    from edge.config import CameraSection


class SimFactory(Protocol):
    """Builds the simulator's source for ``--source sim:SCENARIO``, paced at its frame rate when ``realtime``."""

    def __call__(self, scenario: str, *, realtime: bool) -> FrameSource: ...


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``--source`` value."""

    kind: str  # "camera", "file", "stream", "sim"
    target: str  # device path, file path, URL or scenario name ("" = the simulator's default)


def parse_source(text: str) -> SourceSpec:
    """``0`` / ``/dev/...`` (camera), ``rtsp://``/``http(s)://`` (stream), ``sim[:SCENARIO]``, else a file."""
    text = text.strip()
    if text == "sim" or text.startswith("sim:"):
        return SourceSpec("sim", text[4:])
    if text.isdigit():
        return SourceSpec("camera", f"/dev/video{int(text)}")
    if text.startswith("/dev/"):  # /dev/videoN or a stable name such as /dev/v4l/by-id/usb-...-video-index0
        return SourceSpec("camera", text)
    if re.match(r"^(rtsp|rtsps|http|https)://", text):
        return SourceSpec("stream", text)
    return SourceSpec("file", text)


def make_source(
    text: str,
    *,
    width: int = 1280,
    height: int = 720,
    fps: float = 30.0,
    fourcc: str = "MJPG",
    controls: CameraControls | None = None,
    loop: bool = False,
    realtime: bool = True,
    stall_timeout_s: float = 2.0,
    sim_factory: SimFactory | None = None,
) -> FrameSource:
    """Build (not open) the source named by ``text``; ``sim_factory`` builds the simulator's. ``realtime`` paces a
    video file or the simulator at its frame rate (a live camera paces itself)."""
    spec = parse_source(text)
    if spec.kind == "camera":
        return CameraSource(spec.target, width=width, height=height, fps=fps, fourcc=fourcc, controls=controls)
    if spec.kind == "stream":
        return StreamSource(spec.target, open_timeout_s=max(2.0, 2 * stall_timeout_s), read_timeout_s=stall_timeout_s)
    if spec.kind == "sim":
        if sim_factory is None:
            raise SourceError("the simulated camera is not available in this build")
        return sim_factory(spec.target, realtime=realtime)
    return VideoFileSource(Path(spec.target), loop=loop, realtime=realtime)


def camera_source(
    camera: CameraSection, sim_factory: SimFactory | None = None, *, realtime: bool | None = None
) -> FrameSource:
    """The source a configuration's ``[camera]`` section names, built (not opened); ``realtime`` overrides the
    configured pacing. The one place a section becomes a source (the appliance, ``doctor``, ``rovers enroll``)."""
    return make_source(
        camera.source,
        width=camera.width,
        height=camera.height,
        fps=camera.fps,
        fourcc=camera.fourcc,
        controls=camera.controls,
        loop=camera.loop,
        realtime=camera.realtime if realtime is None else realtime,
        stall_timeout_s=camera.stall_timeout_s,
        sim_factory=sim_factory,
    )
