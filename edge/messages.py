"""The versioned message contract between the edge and the rovers (``shared/schema/``).

The pydantic models here (and those of several boards in :mod:`edge.board_messages`) are the single source of
truth: ``shared/schema/*.schema.json`` are generated from them (:mod:`edge.contract`, ``edge-ips schema --out
shared/schema``) and a test fails when the committed files drift. The hot path does not
build models: :func:`encode_pose` formats the canonical bytes directly, and tests pin that those bytes are exactly
what the model validates and re-serialises.

Numbers are rounded on the wire: positions to 0.01 cm, velocities to 0.1 cm/s, heading to 1e-4 rad, quality to
0.01, capture time to 1 ms. A pose message is at most :data:`POSE_MAX_BYTES` bytes.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationError

from edge.errors import MessageError, describe_validation

VERSION = 1
TOPIC_PREFIX = "ips/v1"
POSE_MAX_BYTES = 160
FORMATION_MAX_BYTES = 512
STATUS_MAX_BYTES = 512
ROVER_STATUS_VERSION = 2  # v1 (seq only) could not say which command a rover applies; see shared/schema/README.md
ROVER_STATUS_PREFIX = f"ips/v{ROVER_STATUS_VERSION}"
ROVER_STATUS_MAX_BYTES = 160

ID_PATTERN = r"^[a-z0-9_-]{1,16}$"
FW_PATTERN = r"^[0-9A-Za-z.+-]{1,16}$"
MAX_INT = 999_999_999  # seq and frame wrap here: below 2**30, so small ints on the ESP8266 (no allocation)
MAX_ABS_CM = 9_999.99  # 100 m: anything beyond is a bug, not a lab
MAX_ABS_CM_S = 999.9  # 10 m/s: far beyond any small rover; the filter output is clipped to it
THETA_LIMIT = 3.1416  # pi rounded up to the wire's 1e-4 rad resolution

RoverId = Annotated[str, StringConstraints(pattern=ID_PATTERN)]


def repeated_ids(ids: Sequence[str]) -> list[str]:
    """The ids ``ids`` names more than once, sorted."""
    return sorted({i for i in ids if ids.count(i) > 1})


def id_problem(ids: Sequence[str], what: str = "rover id") -> str | None:
    """The rule of every list of rover ids (configuration, enrolment, broker logins, formations, the simulator):
    each one an id (:data:`ID_PATTERN`, the topic segment), none named twice. What breaks it, or None."""
    bad = [i for i in ids if not re.fullmatch(ID_PATTERN, i)]  # fullmatch: "$" alone lets "red\n" through
    if bad:
        return f"{what} {bad[0]!r} is not an id: 1-16 of a-z, 0-9, _ and -"
    twice = repeated_ids(ids)
    return f"{', '.join(twice)} named more than once" if twice else None


Cm = Annotated[float, Field(ge=-MAX_ABS_CM, le=MAX_ABS_CM, allow_inf_nan=False)]
CmPerS = Annotated[float, Field(ge=-MAX_ABS_CM_S, le=MAX_ABS_CM_S, allow_inf_nan=False)]
Counter = Annotated[int, Field(ge=0, le=MAX_INT)]
# An int field, not Literal[1]: strict ints refuse 1.0, which the contract forbids (the README's rule).
Version = Annotated[int, Field(ge=VERSION, le=VERSION, json_schema_extra={"const": VERSION})]

_STRICT = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


# -- topics ------------------------------------------------------------------------------------------------------
def pose_topic(rover_id: str) -> str:
    """One topic per rover, as the paper's three topics: ``ips/v1/rovers/<id>/pose``."""
    return f"{TOPIC_PREFIX}/rovers/{rover_id}/pose"


def rover_status_topic(rover_id: str) -> str:
    """A rover's own retained status, rover status v2 (its last will says ``offline``)."""
    return f"{ROVER_STATUS_PREFIX}/rovers/{rover_id}/status"


def edge_status_topic(edge_id: str) -> str:
    """The edge's retained status (its last will says ``offline``)."""
    return f"{TOPIC_PREFIX}/edge/{edge_id}/status"


FORMATION_TOPIC = f"{TOPIC_PREFIX}/formation"
POSE_WILDCARD = f"{TOPIC_PREFIX}/rovers/+/pose"
ROVER_STATUS_WILDCARD = f"{ROVER_STATUS_PREFIX}/rovers/+/status"


# -- models ------------------------------------------------------------------------------------------------------
class PoseV1(BaseModel):
    """One rover's state, one message per rover per processed frame, on ``ips/v1/rovers/<id>/pose``."""

    model_config = ConfigDict(
        **_STRICT,
        title="pose v1",
        json_schema_extra={"x-max-bytes": POSE_MAX_BYTES, "x-topic": "ips/v1/rovers/<id>/pose"},
    )

    v: Version = Field(description="Message version, always 1.")
    id: RoverId = Field(description="Rover id, 1-16 characters of a-z, 0-9, _ and -.")
    seq: Counter = Field(description="Per-rover message counter, increments by one per message.")
    frame: Counter = Field(description="Index of the source frame the pose was measured in.")
    t: float = Field(ge=0.0, lt=1e10, description="Capture time of the frame, Unix seconds (wall clock at grab).")
    x: Cm = Field(description="World x, cm, origin at the bottom-left corner of the working area.")
    y: Cm = Field(description="World y, cm.")
    theta: float | None = Field(
        ge=-THETA_LIMIT, le=THETA_LIMIT, description="Heading, radians in (-pi, pi] (x axis = 0), or null."
    )
    vx: CmPerS | None = Field(description="Velocity along x, cm/s, or null when unknown.")
    vy: CmPerS | None = Field(description="Velocity along y, cm/s, or null when unknown.")
    q: float = Field(ge=0.0, le=1.0, description="Quality / confidence of the measurement, 0..1.")


FormationKind = Literal["line", "rendezvous", "triangle", "stop"]


class FormationV1(BaseModel):
    """The commanded formation, retained on ``ips/v1/formation``."""

    model_config = ConfigDict(
        **_STRICT,
        title="formation v1",
        json_schema_extra={"x-max-bytes": FORMATION_MAX_BYTES, "x-topic": FORMATION_TOPIC, "x-retained": True},
    )

    v: Version = Field(description="Message version, always 1.")
    seq: Counter = Field(
        description="Increments with every new formation command (999999999 is followed by 1); a label for people "
        "and logs: rovers compare whole commands, not seq."
    )
    kind: FormationKind = Field(description="Which formation: line, rendezvous, triangle, or stop (all halt).")
    ids: list[RoverId] = Field(max_length=16, description="Ordered ids of the rovers taking part.")
    spacing: float | None = Field(
        default=None, gt=0.0, le=1000.0, description="Line: distance between neighbours along the line, cm."
    )
    side: float | None = Field(default=None, gt=0.0, le=1000.0, description="Triangle: side length, cm.")
    x: Cm | None = Field(default=None, description="Optional anchor x, cm (line: the line's x; else centre).")
    y: Cm | None = Field(default=None, description="Optional anchor y, cm (the formation's centre).")
    theta: float | None = Field(
        default=None,
        ge=-THETA_LIMIT,
        le=THETA_LIMIT,
        description="Orientation of the formation, rad (line: direction of the line; 0 = along +y).",
    )


EdgeState = Literal["online", "degraded", "offline"]
CameraState = Literal["ok", "starting", "stalled", "missing", "stopped"]


class StatusV1(BaseModel):
    """The edge's health, retained on ``ips/v1/edge/<edge-id>/status``; the last will is ``state: offline``."""

    model_config = ConfigDict(
        **_STRICT,
        title="status v1",
        json_schema_extra={"x-max-bytes": STATUS_MAX_BYTES, "x-topic": "ips/v1/edge/<edge-id>/status"},
    )

    v: Version = Field(description="Message version, always 1.")
    edge: RoverId = Field(description="Edge id (same alphabet as rover ids).")
    state: EdgeState = Field(description="online, degraded (camera or tracking trouble) or offline.")
    camera: CameraState = Field(description="State of the frame source.")
    fps: float = Field(ge=0.0, le=1000.0, description="Processed frames per second over the last interval.")
    rovers: list[RoverId] = Field(max_length=32, description="Rovers seen in the last interval.")
    missing: list[RoverId] = Field(
        default_factory=list, max_length=32, description="Configured rovers not seen in the last interval."
    )
    t: float = Field(ge=0.0, le=1e10, description="Wall-clock time of the status, Unix seconds.")


HaltReason = Literal["none", "probe", "idle", "stop", "stale", "disconnected", "error", "heading"]


class RoverStatusV2(BaseModel):
    """What a rover applies and why its motors are stopped, retained on ``ips/v2/rovers/<id>/status`` (published by
    the rover; its last will is ``state: offline``)."""

    model_config = ConfigDict(
        **_STRICT,
        title="rover status v2",
        json_schema_extra={
            "x-max-bytes": ROVER_STATUS_MAX_BYTES,
            "x-topic": f"{ROVER_STATUS_PREFIX}/rovers/<id>/status",
            "x-retained": True,
        },
    )

    v: Annotated[
        int,
        Field(
            ge=ROVER_STATUS_VERSION,
            le=ROVER_STATUS_VERSION,
            json_schema_extra={"const": ROVER_STATUS_VERSION},
            description="Message version, always 2.",
        ),
    ]
    id: RoverId = Field(description="The rover's id (the topic's <id>).")
    state: Literal["online", "offline"] = Field(description="online, or offline (the last will, or a clean stop).")
    halt: HaltReason = Field(
        description="Why the motors are stopped: none and probe drive; idle, stop, stale, disconnected, error and "
        "heading halt (docs/firmware.md, safety behaviour)."
    )
    formation: FormationKind | None = Field(
        description="Kind of the formation command the rover applies, or null: none received since it (re)connected."
    )
    seq: Counter | None = Field(description="seq of that formation command, or null.")
    fw: Annotated[str, StringConstraints(pattern=FW_PATTERN)] | None = Field(
        description="Firmware version, or null (the last will)."
    )


# -- encoding ----------------------------------------------------------------------------------------------------
def _num(value: float, ndigits: int) -> str:
    r = round(value, ndigits) + 0.0  # + 0.0 turns -0.0 into 0.0
    return repr(r)


def _opt(value: float | None, ndigits: int) -> str:
    return "null" if value is None else _num(value, ndigits)


def wrap_angle(theta_rad: float) -> float:
    """Angle in (-pi, pi]."""
    wrapped = math.remainder(theta_rad, math.tau)
    return math.pi if wrapped <= -math.pi else wrapped


def encode_pose(
    rover_id: str,
    seq: int,
    frame: int,
    t: float,
    x: float,
    y: float,
    theta: float | None,
    vx: float | None,
    vy: float | None,
    q: float,
) -> bytes:
    """Canonical pose v1 bytes (no spaces, fixed key order, rounded numbers), without building a model.

    Counters wrap at :data:`MAX_INT`; ``theta`` outside +-3.1416 is wrapped into (-pi, pi]; ``q`` is clipped to
    0..1. Raises :class:`MessageError` for values the contract cannot carry (NaN, infinities, out-of-range x, y).
    """
    values = (t, x, y, *tuple(v for v in (theta, vx, vy) if v is not None))
    if not all(math.isfinite(v) for v in values) or not math.isfinite(q):
        raise MessageError(f"pose for {rover_id!r}: non-finite value in {(*values, q)}")
    if abs(x) > MAX_ABS_CM or abs(y) > MAX_ABS_CM:
        raise MessageError(f"pose for {rover_id!r}: position ({x}, {y}) cm out of range")
    if theta is not None and not -THETA_LIMIT <= theta <= THETA_LIMIT:
        theta = wrap_angle(theta)
    if vx is not None:
        vx = min(max(vx, -MAX_ABS_CM_S), MAX_ABS_CM_S)
    if vy is not None:
        vy = min(max(vy, -MAX_ABS_CM_S), MAX_ABS_CM_S)
    q = min(max(q, 0.0), 1.0)
    text = (
        f'{{"v":1,"id":"{rover_id}","seq":{seq % (MAX_INT + 1)},"frame":{frame % (MAX_INT + 1)},'
        f'"t":{_num(t, 3)},"x":{_num(x, 2)},"y":{_num(y, 2)},"theta":{_opt(theta, 4)},'
        f'"vx":{_opt(vx, 1)},"vy":{_opt(vy, 1)},"q":{_num(q, 2)}}}'
    )
    return text.encode("ascii")


def dumps(message: BaseModel) -> bytes:
    """Canonical bytes of any contract message: no spaces, declared key order, every field present."""
    if isinstance(message, PoseV1):
        m = message
        return encode_pose(m.id, m.seq, m.frame, m.t, m.x, m.y, m.theta, m.vx, m.vy, m.q)
    return json.dumps(message.model_dump(mode="json"), separators=(",", ":"), allow_nan=False).encode()


def next_seq(seq: int | None) -> int:
    """The formation seq after ``seq`` (None: nothing retained): +1, and 999999999 is followed by 1, not 0 (0 is
    never written, so a wrapped seq never looks like a fresh start)."""
    return 1 if seq is None or seq >= MAX_INT or seq < 0 else seq + 1


# -- decoding ----------------------------------------------------------------------------------------------------
def _loads(model: type[BaseModel], payload: bytes, max_bytes: int) -> Any:
    if len(payload) > max_bytes:
        raise MessageError(f"{model.__name__}: payload of {len(payload)} bytes exceeds {max_bytes}")
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MessageError(f"{model.__name__}: payload is not UTF-8 ({exc.reason})") from exc
    try:
        return model.model_validate_json(text)
    except ValidationError as exc:
        raise MessageError(f"{model.__name__}: {describe_validation(exc)}") from exc


def parse_pose(payload: bytes) -> PoseV1:
    return _loads(PoseV1, payload, POSE_MAX_BYTES)


def parse_formation(payload: bytes) -> FormationV1:
    return _loads(FormationV1, payload, FORMATION_MAX_BYTES)


def parse_status(payload: bytes) -> StatusV1:
    return _loads(StatusV1, payload, STATUS_MAX_BYTES)


def parse_rover_status(payload: bytes) -> RoverStatusV2:
    return _loads(RoverStatusV2, payload, ROVER_STATUS_MAX_BYTES)
