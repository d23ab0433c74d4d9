"""Frame sources: where frames come from (V4L2 camera, video file, RTSP/HTTP stream, simulator).

Every source yields :class:`Frame` objects through the small :class:`FrameSource` protocol. The capture timestamp
is taken at grab (``time.time()`` for the wire, ``time.monotonic()`` for latency) and travels with the frame into
the pose message's ``t``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Frame:
    """One captured frame.

    ``image``: (H, W, 3) uint8, BGR (OpenCV order). ``index``: frame number from the source (0-based).
    ``t_capture_s``: wall-clock Unix seconds at grab. ``t_mono_s``: ``time.monotonic()`` at grab.
    """

    image: NDArray[np.uint8]
    index: int
    t_capture_s: float
    t_mono_s: float


@dataclass(frozen=True)
class SourceInfo:
    """What a source really delivers (a camera may grant less than was requested)."""

    width_px: int
    height_px: int
    fps: float
    description: str


@runtime_checkable
class FrameSource(Protocol):
    """A source of frames. ``open`` before ``read``; ``read`` returns None at the end of a finite stream."""

    def open(self) -> SourceInfo: ...

    def read(self) -> Frame | None: ...

    def close(self) -> None: ...
