"""The messages of several camera boards (``shared/schema/``): each board's detections, and the fusers' status.

A board of several publishes what it measured, one :class:`DetectionsV1` per processed frame; the fusion service
(``edge-ips fuse``) turns them into the canonical poses of :mod:`edge.messages` and publishes its own
:class:`FuserStatusV1`. Rovers never read either. :mod:`edge.contract` lists them with the rest of the contract.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from edge.messages import (
    _STRICT,
    THETA_LIMIT,
    TOPIC_PREFIX,
    Cm,
    Counter,
    RoverId,
    Version,
    _loads,
    repeated_ids,
)

# -- detections: what one camera board measured, for the fusion service (several cameras) ------------------------
DETECTIONS_MAX_BYTES = 12_288
DETECTIONS_MAX_ROVERS = 64
DETECTIONS_MAX_VIEW_POINTS = 8
MAX_COV_CM2 = 1e6  # a variance of (10 m)^2: a detection that uncertain carries no information
MAX_PX = 99_999.9


def detections_topic(edge_id: str) -> str:
    """A board's own measurements, one message per processed frame: ``ips/v1/edge/<edge-id>/detections``."""
    return f"{TOPIC_PREFIX}/edge/{edge_id}/detections"


DETECTIONS_WILDCARD = detections_topic("+")
Px = Annotated[float, Field(ge=-MAX_PX, le=MAX_PX, allow_inf_nan=False)]
Seconds = Annotated[float, Field(ge=0.0, lt=1e10, allow_inf_nan=False)]


class DetectedRoverV1(BaseModel):
    """One rover as one board measured it: a world position with its covariance, heading, quality, pixel."""

    model_config = ConfigDict(**_STRICT, title="detected rover v1")

    id: RoverId = Field(description="Rover id (the marker's colour as this board's tracker knows it).")
    x: Cm = Field(description="Measured world x of the marker centre, cm (the shared floor frame).")
    y: Cm = Field(description="Measured world y, cm.")
    cov: list[Annotated[float, Field(ge=-MAX_COV_CM2, le=MAX_COV_CM2, allow_inf_nan=False)]] = Field(
        min_length=3,
        max_length=3,
        description="Covariance of (x, y) as [xx, xy, yy], cm^2: the calibration's error at this point plus the "
        "detection's pixel noise through the mapping, scaled by image and marker quality; positive definite.",
    )
    theta: float | None = Field(
        ge=-THETA_LIMIT, le=THETA_LIMIT, description="Heading, radians in (-pi, pi], or null when unknown."
    )
    q: float = Field(ge=0.0, le=1.0, description="The tracker's quality of this measurement, 0..1.")
    px: list[Px] = Field(
        min_length=2, max_length=2, description="Image position [u, v] of the marker centre, px (for overlays)."
    )

    @model_validator(mode="after")
    def _positive_definite(self) -> DetectedRoverV1:
        xx, xy, yy = self.cov
        if not (xx > 0.0 and yy > 0.0 and xx * yy - xy * xy > 0.0):
            raise ValueError("cov must be positive definite (xx > 0, yy > 0, xx*yy > xy^2)")
        return self


class DetectionsV1(BaseModel):
    """What one camera board measured in one frame, on ``ips/v1/edge/<edge-id>/detections`` (QoS 0, not retained).

    The fusion service (``edge-ips fuse``) turns every board's detections into the canonical poses; rovers never
    read this topic.
    """

    model_config = ConfigDict(
        **_STRICT,
        title="detections v1",
        json_schema_extra={"x-max-bytes": DETECTIONS_MAX_BYTES, "x-topic": "ips/v1/edge/<edge-id>/detections"},
    )

    v: Version = Field(description="Message version, always 1.")
    edge: RoverId = Field(description="Id of the board that measured (same alphabet as rover ids).")
    seq: Counter = Field(description="Per-board message counter, +1 per message, wraps like pose seq.")
    frame: Counter = Field(description="The board's own frame index.")
    t: Seconds = Field(description="Capture time of the frame, Unix seconds, the board's clock (0.1 ms resolution).")
    ts: Seconds = Field(description="When the board sent the message, Unix seconds, the board's clock.")
    iq: float = Field(ge=0.0, le=1.0, description="Image quality of the frame 0..1 (exposure: dark or clipped).")
    view: list[Annotated[list[Cm], Field(min_length=2, max_length=2)]] = Field(
        max_length=DETECTIONS_MAX_VIEW_POINTS,
        description="The board's view on the floor as a polygon of [x, y] cm corners (empty when unknown).",
    )
    rovers: list[DetectedRoverV1] = Field(
        max_length=DETECTIONS_MAX_ROVERS, description="Every rover this board measured in the frame, ids unique."
    )

    @model_validator(mode="after")
    def _unique_ids(self) -> DetectionsV1:
        twice = repeated_ids([r.id for r in self.rovers])
        if twice:
            raise ValueError(f"{', '.join(twice)} named more than once in one message")
        return self


def parse_detections(payload: bytes) -> DetectionsV1:
    return _loads(DetectionsV1, payload, DETECTIONS_MAX_BYTES)


# -- the fusion service's own status ------------------------------------------------------------------------------
FUSER_STATUS_MAX_BYTES = 16_384


def fuser_status_topic(fuser_id: str) -> str:
    """A fuser's retained status: ``ips/v1/fuser/<fuser-id>/status``."""
    return f"{TOPIC_PREFIX}/fuser/{fuser_id}/status"


FUSER_STATUS_WILDCARD = fuser_status_topic("+")
Ms = Annotated[float, Field(ge=-1e7, le=1e7, allow_inf_nan=False)]


class BoardStateV1(BaseModel):
    """One camera board as a fuser sees it."""

    model_config = ConfigDict(**_STRICT, title="board state v1")

    edge: RoverId = Field(description="The board's id.")
    state: Literal["ok", "silent", "offline"] = Field(
        description="ok: its detections arrive; silent: none for a second or more; offline: its status says so."
    )
    offset_ms: Ms | None = Field(description="Its clock minus the fuser's, ms, as estimated from the data.")
    offset_sigma_ms: Ms | None = Field(description="The estimate's 1-sigma, ms.")
    offset_source: Literal["overlap", "arrival", "overlap+arrival", "reference", "none"] = Field(
        description="What the estimate rests on: rovers seen in an overlap with other boards, arrival times, both."
    )
    age_ms: Ms | None = Field(description="Since its last detections arrived, ms (null: never).")
    stale: Counter = Field(description="Detections dropped as too old on arrival, since the fuser started.")
    rovers: list[RoverId] = Field(max_length=64, description="The rovers in its latest detections.")
    view: list[Annotated[list[Cm], Field(min_length=2, max_length=2)]] = Field(
        max_length=DETECTIONS_MAX_VIEW_POINTS, description="Its view on the floor (from its detections)."
    )


class FuserStatusV1(BaseModel):
    """A fusion service's health, retained on ``ips/v1/fuser/<fuser-id>/status`` (published at a clean stop as
    ``offline``; a crashed fuser's lease is released by its last will on ``ips/v1/fuser/lease``)."""

    model_config = ConfigDict(
        **_STRICT,
        title="fuser status v1",
        json_schema_extra={"x-max-bytes": FUSER_STATUS_MAX_BYTES, "x-topic": "ips/v1/fuser/<fuser-id>/status"},
    )

    v: Version = Field(description="Message version, always 1.")
    fuser: RoverId = Field(description="The fuser's id.")
    state: Literal["active", "standby", "offline"] = Field(
        description="active: it publishes the poses (it holds the lease); standby: it fuses, ready to take over."
    )
    holder: RoverId | None = Field(description="The fuser that holds the lease, as this one sees it.")
    boards: list[BoardStateV1] = Field(max_length=16, description="Every board it has heard of.")
    rovers: list[RoverId] = Field(max_length=64, description="Rovers measured within the timeout.")
    missing: list[RoverId] = Field(max_length=64, description="Rovers seen before, not within the timeout.")
    t: float = Field(ge=0.0, le=1e10, description="Wall-clock time of the status, Unix seconds.")


def parse_fuser_status(payload: bytes) -> FuserStatusV1:
    return _loads(FuserStatusV1, payload, FUSER_STATUS_MAX_BYTES)
