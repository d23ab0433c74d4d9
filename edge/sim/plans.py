"""Scripted trajectories: straights, arcs, turns on the spot, waits and go-to, with trapezoidal speed profiles.

A :class:`Plan`'s pose is an exact function of time, so ground truth can be sampled at any instant (circles of the
paper's Figs. 33-36, the diagonal of Fig. 37, crossings, stops, leaving and re-entering the view). The world
(:mod:`edge.sim.world`) moves scripted rovers along them. Units: cm, s, rad, in the world frame of
:mod:`edge.camera`.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from edge.errors import SimulationError
from edge.messages import wrap_angle


@dataclass(frozen=True)
class Pose:
    x_cm: float
    y_cm: float
    theta_rad: float


@dataclass(frozen=True)
class Straight:
    """Drive ``distance_cm`` forward (negative: backward) at up to ``speed_cm_s``."""

    distance_cm: float
    speed_cm_s: float = 20.0


@dataclass(frozen=True)
class Arc:
    """Drive along a circle of ``radius_cm`` through ``angle_rad`` of heading (positive: left turn, CCW)."""

    radius_cm: float
    angle_rad: float
    speed_cm_s: float = 20.0


@dataclass(frozen=True)
class Turn:
    """Turn on the spot by ``angle_rad`` (positive: CCW) at up to ``omega_rad_s``."""

    angle_rad: float
    omega_rad_s: float = 1.5


@dataclass(frozen=True)
class Wait:
    """Stand still for ``duration_s``."""

    duration_s: float


@dataclass(frozen=True)
class GoTo:
    """Turn on the spot towards ``(x_cm, y_cm)``, then drive straight to it."""

    x_cm: float
    y_cm: float
    speed_cm_s: float = 20.0
    omega_rad_s: float = 1.5


Segment = Straight | Arc | Turn | Wait | GoTo


@dataclass(frozen=True)
class _Profile:
    """Trapezoidal 1-D motion over ``length`` from speed ``v_in`` to ``v_out`` with cruise ``peak``, accel ``a``."""

    length: float
    v_in: float
    peak: float
    v_out: float
    accel: float
    t_acc: float = field(init=False)
    t_cruise: float = field(init=False)
    t_dec: float = field(init=False)

    def __post_init__(self) -> None:
        a = self.accel
        d_acc = (self.peak**2 - self.v_in**2) / (2 * a)
        d_dec = (self.peak**2 - self.v_out**2) / (2 * a)
        d_cruise = max(self.length - d_acc - d_dec, 0.0)
        object.__setattr__(self, "t_acc", (self.peak - self.v_in) / a)
        object.__setattr__(self, "t_cruise", d_cruise / self.peak if self.peak > 0 else 0.0)
        object.__setattr__(self, "t_dec", (self.peak - self.v_out) / a)

    @classmethod
    def plan(cls, length: float, v_in: float, cruise: float, v_out: float, accel: float) -> _Profile:
        peak_reachable = math.sqrt(max((2 * accel * length + v_in**2 + v_out**2) / 2.0, 0.0))
        peak = max(min(cruise, peak_reachable), v_in, v_out)
        return cls(length, v_in, peak, v_out, accel)

    @property
    def duration(self) -> float:
        return self.t_acc + self.t_cruise + self.t_dec

    def at(self, tau: float) -> tuple[float, float]:
        """(distance travelled, speed) at local time ``tau``."""
        a = self.accel
        tau = min(max(tau, 0.0), self.duration)
        if tau <= self.t_acc:
            return self.v_in * tau + 0.5 * a * tau * tau, self.v_in + a * tau
        s_acc = self.v_in * self.t_acc + 0.5 * a * self.t_acc**2
        tau -= self.t_acc
        if tau <= self.t_cruise:
            return s_acc + self.peak * tau, self.peak
        tau -= self.t_cruise
        s = s_acc + self.peak * self.t_cruise + self.peak * tau - 0.5 * a * tau * tau
        return min(s, self.length), self.peak - a * tau


@dataclass(frozen=True)
class _Primitive:
    kind: str  # "line", "arc", "spin", "wait"
    start: Pose
    direction: float  # +1 / -1: forward/backward (line), left/right (arc, spin)
    radius_cm: float
    profile: _Profile | None
    wait_s: float

    @property
    def duration(self) -> float:
        return self.profile.duration if self.profile is not None else self.wait_s

    def sample(self, tau: float) -> tuple[Pose, float, float]:
        """(pose, forward speed cm/s, yaw rate rad/s) at local time ``tau``."""
        p = self.start
        if self.profile is None:
            return p, 0.0, 0.0
        s, speed = self.profile.at(tau)
        d = self.direction
        if self.kind == "line":
            c, si = math.cos(p.theta_rad), math.sin(p.theta_rad)
            return Pose(p.x_cm + d * s * c, p.y_cm + d * s * si, p.theta_rad), d * speed, 0.0
        if self.kind == "arc":
            return _arc_pose(p, d, self.radius_cm, s), speed, d * speed / self.radius_cm
        # spin
        return Pose(p.x_cm, p.y_cm, wrap_angle(p.theta_rad + d * s)), 0.0, d * speed


class Plan:
    """A scripted trajectory: segments executed one after another from ``start``, pose an exact function of time.

    Speeds ramp with ``accel_cm_s2`` (``alpha_rad_s2`` for turns on the spot); consecutive driving segments join
    without stopping (at the lower of their speeds); the rover stops before a turn on the spot or a wait and at the
    end. ``cyclic``: repeat forever (the segments should bring the rover back to ``start``); otherwise the rover
    stays at the final pose.
    """

    def __init__(
        self,
        start: Pose,
        segments: Sequence[Segment],
        *,
        accel_cm_s2: float = 40.0,
        alpha_rad_s2: float = 4.0,
        cyclic: bool = False,
    ) -> None:
        if accel_cm_s2 <= 0 or alpha_rad_s2 <= 0:
            raise SimulationError("plan: accelerations must be positive")
        self.start = start
        self.segments = tuple(segments)
        self.cyclic = cyclic
        self._primitives = _compile(start, self.segments, accel_cm_s2, alpha_rad_s2)
        self._starts = [0.0]
        for prim in self._primitives:
            self._starts.append(self._starts[-1] + prim.duration)
        self.duration_s = self._starts[-1]
        if cyclic and self.duration_s <= 0:
            raise SimulationError("plan: a cyclic plan needs a positive duration")

    def max_wheel_speed_cm_s(self, track_width_cm: float) -> float:
        """Highest wheel speed the plan asks for, for a rover with the given track width."""
        top = 0.0
        for prim in self._primitives:
            if prim.profile is None:
                continue
            peak = prim.profile.peak
            if prim.kind == "line":
                top = max(top, peak)
            elif prim.kind == "arc":
                top = max(top, peak * (1.0 + 0.5 * track_width_cm / prim.radius_cm))
            else:
                top = max(top, peak * 0.5 * track_width_cm)
        return top

    def sample(self, t_s: float) -> tuple[Pose, float, float]:
        """(pose, forward speed cm/s, yaw rate rad/s) at time ``t_s`` since the plan started."""
        if not self._primitives:
            return self.start, 0.0, 0.0
        if t_s < 0:
            t_s = 0.0
        if self.cyclic:
            t_s = math.fmod(t_s, self.duration_s)
        if t_s >= self.duration_s:
            last = self._primitives[-1]
            pose, _, _ = last.sample(last.duration)
            return pose, 0.0, 0.0
        i = bisect.bisect_right(self._starts, t_s) - 1
        i = min(max(i, 0), len(self._primitives) - 1)
        return self._primitives[i].sample(t_s - self._starts[i])

    @property
    def end_pose(self) -> Pose:
        return self.sample(self.duration_s)[0] if not self.cyclic else self.start


def _compile(start: Pose, segments: Sequence[Segment], accel: float, alpha: float) -> list[_Primitive]:
    # Expand GoTo into Turn + Straight and collect (kind, length, cruise, direction, radius) per primitive.
    raw: list[tuple[str, float, float, float, float]] = []
    pose = start
    for seg in segments:
        parts: list[Segment]
        if isinstance(seg, GoTo):
            dx, dy = seg.x_cm - pose.x_cm, seg.y_cm - pose.y_cm
            dist = math.hypot(dx, dy)
            parts = []
            if dist > 1e-9:
                turn = wrap_angle(math.atan2(dy, dx) - pose.theta_rad)
                if abs(turn) > 1e-9:
                    parts.append(Turn(turn, seg.omega_rad_s))
                parts.append(Straight(dist, seg.speed_cm_s))
        else:
            parts = [seg]
        for part in parts:
            entry = _describe(part)
            raw.append(entry)
            pose = _advance(pose, entry)
    # Junction speeds: 0 at the ends and around spins/waits; a driving junction at the lower cruise speed; then
    # forward and backward passes so every segment can reach its exit speed with the given acceleration.
    n = len(raw)
    v = [0.0] * (n + 1)
    for j in range(1, n):
        a, b = raw[j - 1], raw[j]
        if a[0] in ("line", "arc") and b[0] in ("line", "arc") and _forward(a) == _forward(b):
            v[j] = min(a[2], b[2])
    for j in range(n):
        if raw[j][0] in ("line", "arc"):
            v[j + 1] = min(v[j + 1], math.sqrt(v[j] ** 2 + 2 * accel * raw[j][1]))
    for j in range(n - 1, -1, -1):
        if raw[j][0] in ("line", "arc"):
            v[j] = min(v[j], math.sqrt(v[j + 1] ** 2 + 2 * accel * raw[j][1]))
    prims: list[_Primitive] = []
    pose = start
    for j, (kind, length, cruise, direction, radius) in enumerate(raw):
        if kind == "wait":
            prims.append(_Primitive(kind, pose, 1.0, 0.0, None, length))
        elif length <= 0.0:
            continue
        else:
            rate = alpha if kind == "spin" else accel
            profile = _Profile.plan(length, v[j], cruise, v[j + 1], rate)
            prims.append(_Primitive(kind, pose, direction, radius, profile, 0.0))
        pose = _advance(pose, raw[j])
    return prims


def _forward(entry: tuple[str, float, float, float, float]) -> float:
    """+1 when a driving primitive moves the rover forward, -1 backward (arcs always drive forward)."""
    return entry[3] if entry[0] == "line" else 1.0


def _describe(seg: Segment) -> tuple[str, float, float, float, float]:
    if isinstance(seg, Straight):
        _check_speed(seg.speed_cm_s, "Straight")
        return ("line", abs(seg.distance_cm), seg.speed_cm_s, 1.0 if seg.distance_cm >= 0 else -1.0, 0.0)
    if isinstance(seg, Arc):
        _check_speed(seg.speed_cm_s, "Arc")
        if seg.radius_cm <= 0:
            raise SimulationError(f"plan: Arc radius must be positive, got {seg.radius_cm}")
        length = abs(seg.angle_rad) * seg.radius_cm
        return ("arc", length, seg.speed_cm_s, 1.0 if seg.angle_rad >= 0 else -1.0, seg.radius_cm)
    if isinstance(seg, Turn):
        _check_speed(seg.omega_rad_s, "Turn")
        return ("spin", abs(seg.angle_rad), seg.omega_rad_s, 1.0 if seg.angle_rad >= 0 else -1.0, 0.0)
    if isinstance(seg, Wait):
        if seg.duration_s < 0:
            raise SimulationError(f"plan: Wait duration must not be negative, got {seg.duration_s}")
        return ("wait", seg.duration_s, 0.0, 1.0, 0.0)
    raise SimulationError(f"plan: unknown segment {seg!r}")


def _check_speed(speed: float, name: str) -> None:
    if not speed > 0:
        raise SimulationError(f"plan: {name} speed must be positive, got {speed}")


def _advance(pose: Pose, entry: tuple[str, float, float, float, float]) -> Pose:
    kind, length, _, direction, radius = entry
    if kind == "line":
        return Pose(
            pose.x_cm + direction * length * math.cos(pose.theta_rad),
            pose.y_cm + direction * length * math.sin(pose.theta_rad),
            pose.theta_rad,
        )
    if kind == "arc":
        return _arc_pose(pose, direction, radius, length)
    if kind == "spin":
        return Pose(pose.x_cm, pose.y_cm, wrap_angle(pose.theta_rad + direction * length))
    return pose


def _arc_pose(start: Pose, direction: float, radius_cm: float, s_cm: float) -> Pose:
    """Pose after ``s_cm`` along a circle of ``radius_cm`` turning left (+1) or right (-1) from ``start``."""
    cx = start.x_cm - direction * radius_cm * math.sin(start.theta_rad)
    cy = start.y_cm + direction * radius_cm * math.cos(start.theta_rad)
    theta = start.theta_rad + direction * s_cm / radius_cm
    return Pose(
        cx + direction * radius_cm * math.sin(theta), cy - direction * radius_cm * math.cos(theta), wrap_angle(theta)
    )
