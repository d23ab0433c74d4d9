"""The tracking interface: frames in, rover poses out.

The runtime (``edge-ips start``), the offline tracker (``edge-ips track``) and the closed-loop simulator all drive a
:class:`Tracker` frame by frame and turn each :class:`RoverEstimate` into a pose v1 message. What a tracker is
built from lives elsewhere: its settings in ``edge.tracker_config``, the trackers themselves in ``edge.trackers``,
``build_tracker`` in ``edge.trackers.factory``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

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
class RoverEstimate:
    """One rover measured in one frame: world pose (cm, rad, cm/s), image position, quality 0..1."""

    rover_id: str
    x_cm: float
    y_cm: float
    theta_rad: float | None
    vx_cm_s: float | None
    vy_cm_s: float | None
    quality: float
    uv_px: tuple[float, float]
    box_px: tuple[int, int, int, int] | None = None  # the search window (x0, y0, x1, y1), for overlays
    # This frame's own measurement before the filter, and its covariance on the plane (xx, xy, yy cm^2): what a
    # fusion of several cameras needs (it filters the cameras' measurements once, not their filters' outputs).
    measured_xy_cm: tuple[float, float] | None = None
    measured_cov_cm2: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class FrameResult:
    """What the tracker made of one frame: estimates of the rovers it saw, ids of those it did not."""

    frame_index: int
    t_capture_s: float
    t_mono_s: float
    estimates: tuple[RoverEstimate, ...]
    missing: tuple[str, ...]
    stage_ms: dict[str, float] = field(default_factory=dict)


class Tracker(Protocol):
    """Frame in, rover estimates out. Keeps its own state (background model, filters, identities)."""

    def process(self, frame: Frame) -> FrameResult: ...

    def reset(self) -> None:
        """Forget everything seen so far (rovers, background): the next frame is tracked as if it were the first,
        at whatever size it has."""
        ...

    def close(self) -> None:
        """Stop what the tracker runs beside the frame thread (the edge fits' worker process, ``edge.centre_offsets``);
        nothing for a tracker that runs nothing. The tracker is not used after."""
        ...


class StageClock(Protocol):
    """Accumulates the time of named stages (Table IV rows). ``edge.tracking.StageTimes`` implements it."""

    def add(self, stage: str, seconds: float) -> None: ...


class NullClock:
    """A :class:`StageClock` that records nothing."""

    def add(self, stage: str, seconds: float) -> None:
        return None


class StageTimes:
    """Accumulated wall time per named stage within one frame (the rows of the paper's Table IV)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def add(self, stage: str, seconds: float) -> None:
        self.seconds[stage] = self.seconds.get(stage, 0.0) + seconds

    def as_ms(self) -> dict[str, float]:
        return {k: v * 1e3 for k, v in self.seconds.items()}
