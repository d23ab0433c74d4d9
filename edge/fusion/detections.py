"""A board's measurements of one frame as plain data, and their canonical detections v1 bytes.

The hot path (a board publishing 30 messages a second with up to 64 rovers each) formats the bytes directly, as
:func:`edge.messages.encode_pose` does for poses; tests pin that the bytes are exactly what
:class:`edge.board_messages.DetectionsV1` validates and re-serialises. Numbers are rounded on the wire: positions to
0.01 cm, covariances to 1e-5 cm^2 (variances at least 1e-4 cm^2), times to 0.1 ms, pixels to 0.1 px, heading to
1e-4 rad, qualities to 0.01, view corners to 0.1 cm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from edge.board_messages import (
    DETECTIONS_MAX_BYTES,
    DETECTIONS_MAX_ROVERS,
    DETECTIONS_MAX_VIEW_POINTS,
    MAX_COV_CM2,
    MAX_PX,
    DetectionsV1,
)
from edge.errors import MessageError
from edge.messages import MAX_ABS_CM, MAX_INT, THETA_LIMIT, wrap_angle

MIN_VARIANCE_CM2 = 1e-4  # (0.01 cm)^2: the wire's position resolution


@dataclass(frozen=True)
class Detection:
    """One rover measured by one board: world position (cm) with covariance ``(xx, xy, yy)`` cm^2, heading, the
    tracker's quality 0..1 and the marker centre's pixel."""

    rover_id: str
    xy_cm: tuple[float, float]
    cov_cm2: tuple[float, float, float]
    theta_rad: float | None
    quality: float
    uv_px: tuple[float, float]


@dataclass(frozen=True)
class Detections:
    """Everything one board measured in one frame. Times are the board's own clock (Unix seconds): ``t_capture_s``
    at grab, ``t_sent_s`` when the message left. ``view_cm``: the board's view on the floor (polygon corners)."""

    edge_id: str
    seq: int
    frame: int
    t_capture_s: float
    t_sent_s: float
    image_quality: float
    view_cm: tuple[tuple[float, float], ...]
    rovers: tuple[Detection, ...]


def _num(value: float, ndigits: int) -> str:
    return repr(round(float(value), ndigits) + 0.0)  # float(): a numpy scalar's repr is not a JSON number


def _cov(cov: tuple[float, float, float]) -> tuple[float, float, float]:
    """Rounded, clipped and still positive definite after rounding (the off-diagonal shrunk if it has to be)."""
    xx = min(max(round(cov[0], 5), MIN_VARIANCE_CM2), MAX_COV_CM2)
    yy = min(max(round(cov[2], 5), MIN_VARIANCE_CM2), MAX_COV_CM2)
    xy = round(cov[1], 5)
    bound = math.sqrt(xx * yy) * 0.999
    if abs(xy) >= bound:
        xy = math.copysign(math.floor(bound * 1e5) / 1e5, xy)
    return xx, xy + 0.0, yy


def encode_detections(d: Detections) -> bytes:
    """Canonical detections v1 bytes (no spaces, declared key order, rounded numbers), without building a model.

    Raises :class:`MessageError` for what the contract cannot carry: non-finite numbers, positions out of range,
    more than 64 rovers or 8 view corners, a repeated rover id, or a message over the byte budget.
    """
    if len(d.rovers) > DETECTIONS_MAX_ROVERS:
        raise MessageError(f"detections of {d.edge_id!r}: {len(d.rovers)} rovers, at most {DETECTIONS_MAX_ROVERS}")
    if len(d.view_cm) > DETECTIONS_MAX_VIEW_POINTS:
        raise MessageError(f"detections of {d.edge_id!r}: view of {len(d.view_cm)} corners, at most 8")
    if len({r.rover_id for r in d.rovers}) != len(d.rovers):
        raise MessageError(f"detections of {d.edge_id!r}: a rover id appears twice")
    if not all(math.isfinite(v) for v in (d.t_capture_s, d.t_sent_s, d.image_quality)):
        raise MessageError(f"detections of {d.edge_id!r}: non-finite time or quality")
    view = ",".join(f"[{_num(_clip_cm(x), 1)},{_num(_clip_cm(y), 1)}]" for x, y in d.view_cm)
    rovers = ",".join(_rover(d.edge_id, r) for r in d.rovers)
    text = (
        f'{{"v":1,"edge":"{d.edge_id}","seq":{d.seq % (MAX_INT + 1)},"frame":{d.frame % (MAX_INT + 1)},'
        f'"t":{_num(d.t_capture_s, 4)},"ts":{_num(d.t_sent_s, 4)},"iq":{_num(_unit(d.image_quality), 2)},'
        f'"view":[{view}],"rovers":[{rovers}]}}'
    )
    payload = text.encode("ascii")
    if len(payload) > DETECTIONS_MAX_BYTES:
        raise MessageError(f"detections of {d.edge_id!r}: {len(payload)} bytes, at most {DETECTIONS_MAX_BYTES}")
    return payload


def _rover(edge_id: str, r: Detection) -> str:
    values = (*r.xy_cm, *r.cov_cm2, *r.uv_px, r.quality, *(() if r.theta_rad is None else (r.theta_rad,)))
    if not all(math.isfinite(v) for v in values):
        raise MessageError(f"detections of {edge_id!r}: non-finite value for rover {r.rover_id!r}")
    x, y = r.xy_cm
    if abs(x) > MAX_ABS_CM or abs(y) > MAX_ABS_CM:
        raise MessageError(f"detections of {edge_id!r}: rover {r.rover_id!r} at ({x}, {y}) cm, out of range")
    xx, xy, yy = _cov(r.cov_cm2)
    theta = r.theta_rad
    if theta is not None and not -THETA_LIMIT <= theta <= THETA_LIMIT:
        theta = wrap_angle(theta)
    u, v = (min(max(p, -MAX_PX), MAX_PX) for p in r.uv_px)
    return (
        f'{{"id":"{r.rover_id}","x":{_num(x, 2)},"y":{_num(y, 2)},'
        f'"cov":[{_num(xx, 5)},{_num(xy, 5)},{_num(yy, 5)}],'
        f'"theta":{"null" if theta is None else _num(theta, 4)},"q":{_num(_unit(r.quality), 2)},'
        f'"px":[{_num(u, 1)},{_num(v, 1)}]}}'
    )


def _unit(value: float) -> float:
    return min(max(value, 0.0), 1.0)


def _clip_cm(value: float) -> float:
    """A view corner within the contract's range at the view's 0.1 cm resolution (a corner far off is still off)."""
    limit = math.floor(MAX_ABS_CM * 10.0) / 10.0
    return min(max(value, -limit), limit)


def from_message(m: DetectionsV1) -> Detections:
    """The plain form of a validated message."""
    return Detections(
        edge_id=m.edge,
        seq=m.seq,
        frame=m.frame,
        t_capture_s=m.t,
        t_sent_s=m.ts,
        image_quality=m.iq,
        view_cm=tuple((p[0], p[1]) for p in m.view),
        rovers=tuple(
            Detection(
                rover_id=r.id,
                xy_cm=(r.x, r.y),
                cov_cm2=(r.cov[0], r.cov[1], r.cov[2]),
                theta_rad=r.theta,
                quality=r.q,
                uv_px=(r.px[0], r.px[1]),
            )
            for r in m.rovers
        ),
    )
