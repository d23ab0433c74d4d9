"""The simulated world: differential-drive rovers moving on the floor, scripted or driven by wheel commands.

Two ways to move a rover:

* a :class:`edge.sim.plans.Plan` (scripted trajectory: straights, arcs, turns on the spot, waits, go-to) with
  trapezoidal speed profiles. Its pose is an exact function of time, so ground truth can be sampled at any
  instant (circles of the paper's Figs. 33-36, the diagonal of Fig. 37, crossings, stops, leaving and re-entering
  the view);
* wheel commands given step by step (the closed-loop formation experiments): the unicycle model with wheel-speed
  and wheel-acceleration limits, per-wheel gain error and noise, and an optional actuation delay.

Units: cm, s, rad; world frame as in :mod:`edge.camera` (x along the 391.5 cm width, y along 549.5, z up). A rover's
``x_cm, y_cm`` is the centre of its body and of the marker on top; ``theta_rad`` is its heading (0 along +x,
counter-clockwise), wrapped to (-pi, pi].
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from edge.errors import SimulationError
from edge.messages import wrap_angle
from edge.sim.plans import Arc, GoTo, Plan, Pose, Segment, Straight, Turn, Wait

__all__ = [
    "Arc",
    "DriveModel",
    "GoTo",
    "Plan",
    "Pose",
    "RoverState",
    "Segment",
    "Straight",
    "Turn",
    "Wait",
    "WheelCommand",
    "World",
    "WorldState",
]


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
