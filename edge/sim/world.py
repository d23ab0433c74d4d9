"""The simulated world: differential-drive rovers moving on the floor, scripted or driven by wheel commands.

Two ways to move a rover:

* a :class:`Plan` (scripted trajectory: straights, arcs, turns on the spot, waits, go-to) with trapezoidal speed
  profiles. Its pose is an exact function of time, so ground truth can be sampled at any instant (circles of the
  paper's Figs. 33-36, the diagonal of Fig. 37, crossings, stops, leaving and re-entering the view);
* wheel commands given step by step (the closed-loop formation experiments): the unicycle model with wheel-speed
  and wheel-acceleration limits, per-wheel gain error and noise, and an optional actuation delay.

Units: cm, s, rad; world frame as in :mod:`edge.camera` (x along the 391.5 cm width, y along 549.5, z up). A rover's
``x_cm, y_cm`` is the centre of its body and of the marker on top; ``theta_rad`` is its heading (0 along +x,
counter-clockwise), wrapped to (-pi, pi].
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from edge.errors import SimulationError
from edge.messages import wrap_angle


@dataclass(frozen=True)
class Pose:
    x_cm: float
    y_cm: float
    theta_rad: float


@dataclass(frozen=True)
class RoverState:
    """One rover at one instant: marker centre (cm), heading (rad), world velocity (cm/s), body rates."""

    rover_id: str
    x_cm: float
    y_cm: float
    theta_rad: float
    vx_cm_s: float
    vy_cm_s: float
    v_cm_s: float = 0.0
    omega_rad_s: float = 0.0


@dataclass(frozen=True)
class WorldState:
    """All rovers at time ``t_s``."""

    t_s: float
    rovers: tuple[RoverState, ...]

    def by_id(self) -> dict[str, RoverState]:
        return {r.rover_id: r for r in self.rovers}


@dataclass(frozen=True)
class WheelCommand:
    """Left and right wheel speed set-points, cm/s (positive drives forward)."""

    left_cm_s: float
    right_cm_s: float

    @classmethod
    def from_unicycle(cls, v_cm_s: float, omega_rad_s: float, track_width_cm: float) -> WheelCommand:
        half = 0.5 * omega_rad_s * track_width_cm
        return cls(v_cm_s - half, v_cm_s + half)


@dataclass(frozen=True)
class DriveModel:
    """Differential-drive hardware of a rover.

    ``motor_gain_sigma``: per-wheel static gain error (fraction, drawn once per rover from the seed: one wheel a bit
    faster than the other, the cause of a real rover's curved "straight" line). ``motor_noise_sigma``: relative
    wheel-speed noise drawn every step. ``delay_s``: actuation delay from command to wheel. ``deadband_cm_s``:
    set-points below it do not turn the wheel (PWM dead zone).
    """

    track_width_cm: float = 15.0
    max_wheel_speed_cm_s: float = 35.0
    max_wheel_accel_cm_s2: float | None = 150.0
    motor_gain_sigma: float = 0.0
    motor_noise_sigma: float = 0.0
    delay_s: float = 0.0
    deadband_cm_s: float = 0.0

    def __post_init__(self) -> None:
        if self.track_width_cm <= 0 or self.max_wheel_speed_cm_s <= 0:
            raise SimulationError("drive model: track width and maximum wheel speed must be positive")
        if self.delay_s < 0 or self.motor_gain_sigma < 0 or self.motor_noise_sigma < 0 or self.deadband_cm_s < 0:
            raise SimulationError("drive model: delay, noise and dead band must not be negative")


# -- scripted trajectories --------------------------------------------------------------------------------------
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


# -- the world -------------------------------------------------------------------------------------------------
@dataclass
class _Driven:
    """Mutable state of a rover moved by wheel commands."""

    x_cm: float
    y_cm: float
    theta_rad: float
    left_cm_s: float = 0.0
    right_cm_s: float = 0.0
    command: WheelCommand = WheelCommand(0.0, 0.0)
    pending: deque[tuple[float, WheelCommand]] = field(default_factory=deque)
    gain_left: float = 1.0
    gain_right: float = 1.0


class World:
    """Rovers on the floor. Each rover either follows a :class:`Plan` or is driven by wheel commands.

    ``rovers``: rover id -> starting :class:`Pose` (commanded rovers) or :class:`Plan` (scripted rovers).
    ``step(dt_s, commands)`` advances time; ``state()`` is the current :class:`WorldState`. A world with only
    scripted rovers can also be sampled at any time with ``state_at(t_s)``.
    """

    def __init__(
        self,
        rovers: Mapping[str, Pose | Plan],
        drive: DriveModel | None = None,
        *,
        seed: int = 0,
        substep_s: float = 0.005,
    ) -> None:
        if not rovers:
            raise SimulationError("world: at least one rover is needed")
        self.drive = drive or DriveModel()
        self.t_s = 0.0
        self._substep_s = substep_s
        self._ids = tuple(rovers)
        self._plans: dict[str, Plan] = {}
        self._driven: dict[str, _Driven] = {}
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
        for rover_id, how in rovers.items():
            if isinstance(how, Plan):
                top = how.max_wheel_speed_cm_s(self.drive.track_width_cm)
                if top > self.drive.max_wheel_speed_cm_s + 1e-9:
                    raise SimulationError(
                        f"world: rover {rover_id!r}: its plan needs {top:.1f} cm/s at a wheel, above the "
                        f"{self.drive.max_wheel_speed_cm_s:.1f} cm/s limit"
                    )
                self._plans[rover_id] = how
            else:
                gains = 1.0 + self.drive.motor_gain_sigma * self._rng.standard_normal(2)
                self._driven[rover_id] = _Driven(
                    how.x_cm, how.y_cm, how.theta_rad, gain_left=gains[0], gain_right=gains[1]
                )

    @property
    def rover_ids(self) -> tuple[str, ...]:
        return self._ids

    @property
    def scripted(self) -> bool:
        """True when every rover follows a plan (the state is then a pure function of time)."""
        return not self._driven

    def step(self, dt_s: float, commands: Mapping[str, WheelCommand | tuple[float, float]] | None = None) -> WorldState:
        """Advance by ``dt_s``. ``commands``: rover id -> :class:`WheelCommand` or ``(v_cm_s, omega_rad_s)``.

        A commanded rover keeps its last command until a new one arrives (motors hold their duty).
        """
        if dt_s < 0:
            raise SimulationError(f"world: time step must not be negative, got {dt_s}")
        for rover_id, cmd in (commands or {}).items():
            rover = self._driven.get(rover_id)
            if rover is None:
                known = ", ".join(sorted(self._driven)) or "none"
                raise SimulationError(f"world: no commanded rover {rover_id!r} (commanded rovers: {known})")
            wheel = (
                cmd if isinstance(cmd, WheelCommand) else WheelCommand.from_unicycle(*cmd, self.drive.track_width_cm)
            )
            rover.pending.append((self.t_s + self.drive.delay_s, wheel))
        remaining = dt_s
        while remaining > 1e-12:
            h = min(self._substep_s, remaining)
            for rover in self._driven.values():
                self._integrate(rover, h)
            self.t_s += h
            remaining -= h
        return self.state()

    def _integrate(self, rover: _Driven, h: float) -> None:
        d = self.drive
        while rover.pending and rover.pending[0][0] <= self.t_s + 1e-12:
            rover.command = rover.pending.popleft()[1]
        targets = []
        for target, gain in ((rover.command.left_cm_s, rover.gain_left), (rover.command.right_cm_s, rover.gain_right)):
            if abs(target) < d.deadband_cm_s:
                target = 0.0
            target = max(-d.max_wheel_speed_cm_s, min(d.max_wheel_speed_cm_s, target)) * gain
            targets.append(target)
        new = []
        for current, target in zip((rover.left_cm_s, rover.right_cm_s), targets, strict=True):
            if d.max_wheel_accel_cm_s2 is not None:
                step = d.max_wheel_accel_cm_s2 * h
                target = current + max(-step, min(step, target - current))
            new.append(target)
        rover.left_cm_s, rover.right_cm_s = new
        left, right = rover.left_cm_s, rover.right_cm_s
        if d.motor_noise_sigma > 0:
            noise = 1.0 + d.motor_noise_sigma * self._rng.standard_normal(2)
            left, right = left * float(noise[0]), right * float(noise[1])
        v = 0.5 * (left + right)
        omega = (right - left) / d.track_width_cm
        th = rover.theta_rad
        if abs(omega) < 1e-9:  # exact unicycle integration over the sub-step
            rover.x_cm += v * h * math.cos(th)
            rover.y_cm += v * h * math.sin(th)
        else:
            th1 = th + omega * h
            rover.x_cm += v / omega * (math.sin(th1) - math.sin(th))
            rover.y_cm -= v / omega * (math.cos(th1) - math.cos(th))
        rover.theta_rad = wrap_angle(th + omega * h)

    def state(self) -> WorldState:
        return WorldState(self.t_s, tuple(self._rover_state(i, self.t_s) for i in self._ids))

    def state_at(self, t_s: float) -> WorldState:
        """The state at any time; only for worlds whose rovers all follow plans."""
        if not self.scripted:
            raise SimulationError("world: state_at() needs every rover to follow a plan; step() a commanded world")
        return WorldState(t_s, tuple(self._rover_state(i, t_s) for i in self._ids))

    def _rover_state(self, rover_id: str, t_s: float) -> RoverState:
        plan = self._plans.get(rover_id)
        if plan is not None:
            pose, v, omega = plan.sample(t_s)
        else:
            r = self._driven[rover_id]
            pose = Pose(r.x_cm, r.y_cm, r.theta_rad)
            v = 0.5 * (r.left_cm_s + r.right_cm_s)
            omega = (r.right_cm_s - r.left_cm_s) / self.drive.track_width_cm
        c, s = math.cos(pose.theta_rad), math.sin(pose.theta_rad)
        return RoverState(rover_id, pose.x_cm, pose.y_cm, wrap_angle(pose.theta_rad), v * c, v * s, v, omega)
