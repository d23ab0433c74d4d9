"""The tracking pipeline's interface: what a processed frame yields, and the typed tracker configuration.

The runtime (``edge-ips start``), the offline tracker (``edge-ips track``) and the closed-loop simulator all drive a
:class:`Tracker` frame by frame and turn each :class:`RoverEstimate` into a pose v1 message.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from pydantic import BaseModel, ConfigDict, Field

from edge.messages import ID_PATTERN
from edge.sources import Frame


class RoverConfig(BaseModel):
    """One rover to track: its id (the topic name) and its marker colour."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str = Field(pattern=ID_PATTERN, description="Rover id, also the MQTT topic segment.")
    color_bgr: tuple[int, int, int] = Field(description="Nominal marker colour as seen by the camera, B, G, R 0-255.")


DEFAULT_ROVERS = (
    RoverConfig(id="red", color_bgr=(40, 40, 200)),
    RoverConfig(id="green", color_bgr=(60, 170, 40)),
    RoverConfig(id="blue", color_bgr=(190, 90, 30)),
)


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
