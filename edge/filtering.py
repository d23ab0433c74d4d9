"""Per-rover constant-velocity Kalman filter: velocity, spike rejection, and no lag in a turn.

The paper's centroid tracker shows spikes and needs 'filtration' (Table V). Here every rover's world position is
filtered by a constant-velocity Kalman filter (state ``x, y, vx, vy``, white-noise acceleration):

* **Spikes**: a measurement whose normalised innovation squared (NIS) exceeds the gate, and which is more than
  ``spike_min_cm`` away, is rejected and the filter coasts on its prediction. A rover that really jumped shows
  the same offset again: after ``confirm_after`` consistent rejections the filter moves to the new place.
* **No lag in a turn**: when an innovation is larger than the prediction's uncertainty explains (NIS above the
  95% point), the prediction is trusted less for that step (its covariance is scaled by NIS / 6, a fading-memory
  step), so the filter follows a turning or braking rover at once and still smooths a straight one.
* **Velocity** is the filter's; it is reported only after two measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
CLEAR_VELOCITY_SIGMAS = 3.0  # a velocity this many of its own sigmas from zero has a direction (a heading's front)
CLEAR_VELOCITY_UPDATES = 10  # ... once this many measurements are in (from two or three, the noise's direction)


def largest_sigma(var_x: float, cov_xy: float, var_y: float) -> float:
    """The standard deviation along the largest axis of the 2 x 2 covariance ``[[var_x, cov_xy], [cov_xy, var_y]]``."""
    half = 0.5 * (var_x + var_y)
    return math.sqrt(max(half + math.sqrt(max(0.25 * (var_x - var_y) ** 2 + cov_xy * cov_xy, 0.0)), 0.0))


def clear_velocity(
    velocity: tuple[float, float],
    covariance: tuple[float, float, float],
    updates: int,
    sigmas: float = CLEAR_VELOCITY_SIGMAS,
) -> tuple[float, float] | None:
    """A filter's ``velocity`` when its speed is at least ``sigmas`` times its own 1-sigma uncertainty (the largest
    axis of its ``covariance``: var x, cov, var y) and :data:`CLEAR_VELOCITY_UPDATES` measurements are in
    (``updates``), else None: a standing rover's velocity is its measurements' noise, in no direction, and from a
    few noisier than the filter was told (a harsh stream's far side) often several of its sigmas."""
    if updates < CLEAR_VELOCITY_UPDATES:
        return None
    return velocity if math.hypot(*velocity) >= sigmas * largest_sigma(*covariance) else None


@dataclass(frozen=True)
class FilterSettings:
    """Tuning of :class:`ConstantVelocityFilter` (units in the names)."""

    accel_sigma_cm_s2: float = 40.0
    gate_nis: float = 16.0  # chi-square with 2 dof: 16 is about 4 sigma, P(false reject) ~ 3e-4
    spike_min_cm: float = 2.0  # innovations smaller than this are never spikes (a manoeuvre, not a glitch)
    confirm_after: int = 2
    confirm_radius_cm: float = 5.0
    fade_nis: float = 6.0  # chi-square with 2 dof at 95%: above it the prediction is trusted less
    max_fade: float = 100.0
    initial_speed_sigma_cm_s: float = 50.0


class ConstantVelocityFilter:
    """One rover's filter. ``predict(dt_s)`` then ``update(z_cm, r_cm2)`` per frame; only ``predict`` when unseen.

    The state (``x``: 4 floats) and its covariance (``p``: 16 floats, row by row) are plain Python floats: a 4-state
    filter is a hundred multiplications, which numpy's per-call cost makes ten times slower."""

    def __init__(self, settings: FilterSettings, xy_cm: tuple[float, float], r_cm2: FloatArray) -> None:
        self.settings = settings
        self.updates = 1
        self.rejected = 0
        self.last_fade = 1.0
        self._pending: list[FloatArray] = []
        self._dt = 1.0 / 30.0
        self._at_frame_time = False  # back_to_frame_time has moved the estimate to the frame's time
        self._restart(float(xy_cm[0]), float(xy_cm[1]), 0.0, 0.0, r_cm2)

    def _restart(self, x: float, y: float, vx: float, vy: float, r_cm2: FloatArray) -> None:
        (r00, r01), (r10, r11) = np.asarray(r_cm2, dtype=np.float64).tolist()
        speed2 = self.settings.initial_speed_sigma_cm_s**2
        self.x = [x, y, vx, vy]
        self.p = [r00, r01, 0.0, 0.0, r10, r11, 0.0, 0.0, 0.0, 0.0, speed2, 0.0, 0.0, 0.0, 0.0, speed2]

    def shift(self, dx_cm: float, dy_cm: float) -> None:
        """Move the position estimate by (dx, dy): the measurements' reference moved (a centre correction was
        learned, ``edge.centre_offsets``), not the rover; the next measurement is then no spike."""
        self.x = [self.x[0] + dx_cm, self.x[1] + dy_cm, self.x[2], self.x[3]]

    # -- state ------------------------------------------------------------------------------------------------
    @property
    def position(self) -> tuple[float, float]:
        return self.x[0], self.x[1]

    @property
    def velocity(self) -> tuple[float, float] | None:
        """(vx, vy) cm/s once two measurements have been fused, else None."""
        return (self.x[2], self.x[3]) if self.updates >= 2 else None

    def clear_velocity(self, sigmas: float = CLEAR_VELOCITY_SIGMAS) -> tuple[float, float] | None:
        """The velocity when it is clear of its own noise (:func:`clear_velocity`), else None."""
        p = self.p
        return clear_velocity((self.x[2], self.x[3]), (p[10], p[11], p[15]), self.updates, sigmas)

    def direction_sigma_rad(self) -> float:
        """1-sigma of the direction of motion: the velocity's uncertainty across it over the speed (inf standing)."""
        vx, vy = self.x[2], self.x[3]
        speed2 = vx * vx + vy * vy
        if speed2 <= 0.0:
            return math.inf
        p = self.p
        across = (vy * vy * p[10] - 2.0 * vx * vy * p[11] + vx * vx * p[15]) / speed2
        return math.sqrt(max(across, 0.0) / speed2)

    @property
    def position_sigma_cm(self) -> float:
        """1-sigma radius of the position uncertainty (largest axis)."""
        return largest_sigma(self.p[0], self.p[1], self.p[5])

    @property
    def on_frame_time(self) -> bool:
        """Has :meth:`back_to_frame_time` moved the estimate to the frame's time (it followed measurements taken at
        their rows' time before)?"""
        return self._at_frame_time

    def back_to_frame_time(
        self, z_cm: tuple[float, float], r_cm2: FloatArray, delay_s: float
    ) -> tuple[tuple[float, float], FloatArray]:
        """A measurement taken ``delay_s`` after the frame's time (its row's exposure under a rolling shutter;
        negative: before it) moved to the frame's time along the predicted velocity, its covariance widened by the
        velocity's over ``delay_s``; as it is while the filter has no velocity (its first two measurements). The
        first time, the estimate itself, which followed measurements taken at their rows' time, is moved the same
        way, so the change shows as no step (a step read as braking halved the velocity for several frames)."""
        v = self.velocity
        if v is None or delay_s == 0.0:
            return z_cm, r_cm2
        if not self._at_frame_time:
            self._at_frame_time = True
            self.shift(-delay_s * v[0], -delay_s * v[1])
        p, d2 = self.p, delay_s * delay_s
        widened = np.asarray(r_cm2, dtype=np.float64) + d2 * np.array([[p[10], p[11]], [p[14], p[15]]])
        return (z_cm[0] - delay_s * v[0], z_cm[1] - delay_s * v[1]), widened

    # -- steps ------------------------------------------------------------------------------------------------
    def predict(self, dt_s: float) -> None:
        """Propagate the state by ``dt_s`` (constant velocity, white-noise acceleration): ``x = F x``,
        ``P = F P F^T + Q``, with ``F`` adding ``dt`` times the velocity to the position."""
        self._dt = dt = max(float(dt_s), 1e-4)
        x0, x1, x2, x3 = self.x
        self.x = [x0 + dt * x2, x1 + dt * x3, x2, x3]
        q = self.settings.accel_sigma_cm_s2**2
        q_pos, q_cross, q_vel = dt**4 / 4.0 * q, dt**3 / 2.0 * q, dt**2 * q
        p00, p01, p02, p03, p10, p11, p12, p13, p20, p21, p22, p23, p30, p31, p32, p33 = self.p
        # F P: rows 0 and 1 gain dt times rows 2 and 3
        a00, a01, a02, a03 = p00 + dt * p20, p01 + dt * p21, p02 + dt * p22, p03 + dt * p23
        a10, a11, a12, a13 = p10 + dt * p30, p11 + dt * p31, p12 + dt * p32, p13 + dt * p33
        # (F P) F^T: columns 0 and 1 gain dt times columns 2 and 3; plus Q
        out = [
            a00 + dt * a02 + q_pos, a01 + dt * a03, a02 + q_cross, a03,
            a10 + dt * a12, a11 + dt * a13 + q_pos, a12, a13 + q_cross,
            p20 + dt * p22 + q_cross, p21 + dt * p23, p22 + q_vel, p23,
            p30 + dt * p32, p31 + dt * p33 + q_cross, p32, p33 + q_vel,
        ]  # fmt: skip
        self.p = out

    def update(self, z_cm: FloatArray, r_cm2: FloatArray) -> bool:
        """Fuse a measurement; returns False when it was rejected as a spike (the state is then unchanged).

        A measurement far outside the gate (and more than ``spike_min_cm`` away) is a spike. One that is merely
        surprising (NIS above ``fade_nis``) means the rover is manoeuvring: the prediction's covariance is scaled
        up by NIS / fade_nis before fusing (a fading-memory step), so the estimate follows at once instead of
        lagging. A run of ``confirm_after`` spikes that agree with each other is a real jump: the filter moves
        there, keeping the velocity the jump implies.
        """
        z0, z1 = np.asarray(z_cm, dtype=np.float64).tolist()
        (r00, r01), (r10, r11) = np.asarray(r_cm2, dtype=np.float64).tolist()
        nu0, nu1 = z0 - self.x[0], z1 - self.x[1]
        p = self.p
        s00, s01, s10, s11 = _inv2(p[0] + r00, p[1] + r01, p[4] + r10, p[5] + r11)
        nis = (nu0 * s00 + nu1 * s10) * nu0 + (nu0 * s01 + nu1 * s11) * nu1
        if nis > self.settings.gate_nis and math.hypot(nu0, nu1) > self.settings.spike_min_cm:
            self._pending.append(np.array([z0, z1]))
            self.rejected += 1
            if len(self._pending) >= self.settings.confirm_after:
                spread = max(float(np.hypot(*(q - self._pending[-1]))) for q in self._pending)
                if spread <= self.settings.confirm_radius_cm * len(self._pending):
                    self._jump(r_cm2)
                    return True
                self._pending = self._pending[-1:]
            return False
        self._pending.clear()
        self.last_fade = 1.0
        if nis > self.settings.fade_nis:
            self.last_fade = fade = min(nis / self.settings.fade_nis, self.settings.max_fade)
            p = [v * fade for v in p]
            s00, s01, s10, s11 = _inv2(p[0] + r00, p[1] + r01, p[4] + r10, p[5] + r11)
        # gain K = P[:, :2] S^-1 (4 x 2); x += K nu; P -= K P[:2, :], then symmetrised
        p00, p01, p02, p03, p10, p11, p12, p13, p20, p21, p22, p23, p30, p31, p32, p33 = p
        k00, k01 = p00 * s00 + p01 * s10, p00 * s01 + p01 * s11
        k10, k11 = p10 * s00 + p11 * s10, p10 * s01 + p11 * s11
        k20, k21 = p20 * s00 + p21 * s10, p20 * s01 + p21 * s11
        k30, k31 = p30 * s00 + p31 * s10, p30 * s01 + p31 * s11
        x0, x1, x2, x3 = self.x
        self.x = [
            x0 + k00 * nu0 + k01 * nu1,
            x1 + k10 * nu0 + k11 * nu1,
            x2 + k20 * nu0 + k21 * nu1,
            x3 + k30 * nu0 + k31 * nu1,
        ]
        n00, n01 = p00 - (k00 * p00 + k01 * p10), p01 - (k00 * p01 + k01 * p11)
        n02, n03 = p02 - (k00 * p02 + k01 * p12), p03 - (k00 * p03 + k01 * p13)
        n10, n11 = p10 - (k10 * p00 + k11 * p10), p11 - (k10 * p01 + k11 * p11)
        n12, n13 = p12 - (k10 * p02 + k11 * p12), p13 - (k10 * p03 + k11 * p13)
        n20, n21 = p20 - (k20 * p00 + k21 * p10), p21 - (k20 * p01 + k21 * p11)
        n22, n23 = p22 - (k20 * p02 + k21 * p12), p23 - (k20 * p03 + k21 * p13)
        n30, n31 = p30 - (k30 * p00 + k31 * p10), p31 - (k30 * p01 + k31 * p11)
        n32, n33 = p32 - (k30 * p02 + k31 * p12), p33 - (k30 * p03 + k31 * p13)
        a01, a02, a03 = 0.5 * (n01 + n10), 0.5 * (n02 + n20), 0.5 * (n03 + n30)
        a12, a13, a23 = 0.5 * (n12 + n21), 0.5 * (n13 + n31), 0.5 * (n23 + n32)
        self.p = [
            n00, a01, a02, a03,
            a01, n11, a12, a13,
            a02, a12, n22, a23,
            a03, a13, a23, n33,
        ]  # fmt: skip
        self.updates += 1
        return True

    def _jump(self, r_cm2: FloatArray) -> None:
        z = self._pending[-1]
        span = (len(self._pending) - 1) * self._dt
        v = (z - self._pending[0]) / span if span > 0 else np.zeros(2)
        self._restart(float(z[0]), float(z[1]), float(v[0]), float(v[1]), r_cm2)
        self.updates = 2 if span > 0 else 1
        self._pending.clear()


class FilterFactory(Protocol):
    """Makes each rover's filter at its first measurement (the pipeline holds one, chosen at build time)."""

    def create_filter(self, xy_cm: tuple[float, float], r_cm2: FloatArray) -> ConstantVelocityFilter: ...


@dataclass(frozen=True)
class ConstantVelocityFilterFactory:
    """A :class:`FilterFactory` of :class:`ConstantVelocityFilter` with one set of ``settings``."""

    settings: FilterSettings = FilterSettings()

    def create_filter(self, xy_cm: tuple[float, float], r_cm2: FloatArray) -> ConstantVelocityFilter:
        return ConstantVelocityFilter(self.settings, xy_cm, r_cm2)


MIN_EDGE_COHERENCE = 0.3  # below, the edges show no rectangle and the axis is the blob's (refine.marker_axis)
STRONG_EDGE_COHERENCE = 0.5  # from here, the edges' axis is taken whatever the motion says
MAX_OFF_MOTION_RAD = math.radians(20.0)  # weakly coherent edges this far from the direction of motion give way to it
MOTION_AXIS_MIN_SPEED_CM_S = 6.0  # slower, the filter's direction of motion scatters too much to stand for the axis


def checked_axis(axis_rad: float, coherence: float, velocity_cm_s: tuple[float, float] | None) -> float:
    """A one-colour marker's long axis (modulo pi) from this frame's measurement ``axis_rad`` and the ``coherence``
    of the edges it came from (0: the blob's principal axis), checked against the rover's velocity (the filter's).

    The edges give the marker's orientation modulo 90 degrees; which of the two is the long axis comes from the
    blob's elongation, and where the edges show no rectangle the blob's second moments stand in altogether. A
    far-side marker through a blurred 4:2:0 stream at quality 60 is a smudge of 25 x 8 pixels: on the family's
    `crowd` clip with seed 4321 (that camera, eight hues, white bodies) the elongation picked the short axis in one
    frame of three for a second and more, the blob's axis was 20-25 degrees off for seconds, and weakly coherent
    edges now and then 30 degrees off. A differential drive moves along its axis, so while the rover drives at a
    fair speed its direction of motion is the axis too, give or take the filter's lag in a turn and its scatter (a
    few degrees at 15-20 cm/s): it picks the long one of the edges' two directions, and stands in for a blob's
    axis and for weakly coherent edges more than ``MAX_OFF_MOTION_RAD`` off it. Standing or crawling, the
    measurement is all there is.
    """
    axis = math.remainder(axis_rad, math.pi)
    if velocity_cm_s is None or math.hypot(*velocity_cm_s) < MOTION_AXIS_MIN_SPEED_CM_S:
        return axis
    motion = math.atan2(velocity_cm_s[1], velocity_cm_s[0])
    if coherence < MIN_EDGE_COHERENCE:
        return math.remainder(motion, math.pi)
    if abs(math.remainder(axis - motion, math.pi)) > 0.25 * math.pi:  # the edges' other direction is the long one
        axis = math.remainder(axis + 0.5 * math.pi, math.pi)
    off = abs(math.remainder(axis - motion, math.pi))
    return axis if coherence >= STRONG_EDGE_COHERENCE or off <= MAX_OFF_MOTION_RAD else math.remainder(motion, math.pi)


def axis_heading(
    axis_rad: float | None,
    velocity_cm_s: tuple[float, float] | None,
    last_heading_rad: float | None,
    min_speed_cm_s: float,
) -> float | None:
    """A one-colour marker's heading: its long axis (``axis_rad``, modulo pi, from the marker's edges) pointed the
    way the rover drives while it moves faster than ``min_speed_cm_s``, else the way it pointed last (a rover turning
    on the spot or standing keeps its front), else None.

    The direction of motion alone (the filter's velocity) lags in a turn and scatters at low speed: 12 degrees at
    the 95th percentile in turns, where the axis of the marker's edges is within a degree or two; the velocity is
    only needed to tell the front end from the back. Without an axis, the direction of motion while moving.
    """
    speed = math.hypot(*velocity_cm_s) if velocity_cm_s is not None else 0.0
    moving = velocity_cm_s is not None and speed >= min_speed_cm_s
    if axis_rad is None:
        return math.atan2(velocity_cm_s[1], velocity_cm_s[0]) if moving and velocity_cm_s is not None else None
    if moving and velocity_cm_s is not None:
        reference = math.atan2(velocity_cm_s[1], velocity_cm_s[0])
    elif last_heading_rad is not None:
        reference = last_heading_rad
    else:
        return None
    return (
        axis_rad
        if abs(math.remainder(axis_rad - reference, math.tau)) <= 0.5 * math.pi
        else axis_rad + (math.pi if axis_rad <= 0 else -math.pi)
    )


def _inv2(a: float, b: float, c: float, d: float) -> tuple[float, float, float, float]:
    """Inverse of the 2x2 matrix ``[[a, b], [c, d]]``, row by row."""
    det = a * d - b * c
    return d / det, -b / det, -c / det, a / det


HEADING_ACCEL_SIGMA_RAD_S2 = 4.0  # how fast a rover's turn rate may change (a turn starts or ends in about 0.2 s)
HEADING_RESET_RAD = math.radians(60.0)  # a heading this far from the filtered one starts the filter afresh
SCATTER_FRAMES = 15.0  # a rover's own headings' scatter is the running mean of about this many frames' ...
SCATTER_CAP = 3.0  # ... normalised innovations, each capped at this many sigmas (one wild frame is not a trend)
SCATTER_MAX = 4.0  # a sigma is widened at most this many times by it
SMALL_MARKER_PX = 800.0  # a marker smaller than this in the image: its edges' axis scatters more than they look
SMALL_MARKER_POWER = 0.6  # ... as (SMALL_MARKER_PX / its pixels) to this power (a line fit's: 0.75)


def heading_sigma_rad(coherence: float, marker_px: float = math.inf) -> float:
    """The scatter of one frame's heading from a one-colour marker: from clearly coherent edges a degree or two, from
    weakly coherent ones a few, from the blob's axis or the direction of motion (which stand in for them below
    ``MIN_EDGE_COHERENCE``, ``checked_axis``) several.

    Edges' coherence says how clearly they show a rectangle, not how many pixels show it: a far-side marker of 200
    pixels through a blurred 4:2:0 stream gives as coherent edges as a near one of 1600, and an axis 4-5 times as
    scattered. A line fitted to ``n`` pixels scatters as ``n ** -1.5``, a marker's axis as its area ``marker_px``
    to the power -0.75; the camera family's falls as -0.6 (blur and chroma spread are not white noise), so edges'
    sigma grows by ``(SMALL_MARKER_PX / marker_px) ** SMALL_MARKER_POWER`` below that size."""
    if coherence >= MIN_EDGE_COHERENCE:
        small = (SMALL_MARKER_PX / marker_px) ** SMALL_MARKER_POWER if 0.0 < marker_px < SMALL_MARKER_PX else 1.0
        return math.radians(1.5 if coherence >= STRONG_EDGE_COHERENCE else 4.0) * small
    return math.radians(8.0)


class HeadingFilter:
    """A one-colour marker's heading through time: angle and turn rate, a Kalman filter whose measurements are each
    frame's heading with the scatter of where it came from (:func:`heading_sigma_rad`).

    One frame's axis from a far-side marker through a harsh stream is 10-20 degrees off now and then while its edges
    still look coherent; the rover's heading cannot move that much in a frame. The turn rate follows turns (no lag
    once a turn is under way), and a heading more than :data:`HEADING_RESET_RAD` from the filtered one (the rover
    reversed, or was lost and found turned) starts it afresh.

    Each frame's own heading (not the direction of motion given with a gate) is also weighed by how far this
    rover's recent ones fell from the prediction: ``scatter`` is the running mean over :data:`SCATTER_FRAMES`
    frames of their normalised innovation squared (each capped at :data:`SCATTER_CAP` sigmas), and a sigma is
    widened by its square root when that is over 1 (at most :data:`SCATTER_MAX` times), never narrowed: a far-side
    marker through a harsh stream scatters more than its coherence and size tell, a near one does not (innovation-
    based measurement noise, as adaptive Kalman filters estimate it)."""

    def __init__(self, accel_sigma_rad_s2: float = HEADING_ACCEL_SIGMA_RAD_S2) -> None:
        self.q = accel_sigma_rad_s2**2
        self.angle: float | None = None
        self.rate = 0.0
        self.p = [0.0, 0.0, 0.0, 0.0]
        self.t_s = 0.0
        self.scatter = 1.0  # kept through a reset: it belongs to where the rover is seen and through which camera

    def update(self, z_rad: float, sigma_rad: float, t_s: float, gate_rad: float | None = None) -> float:
        """Take the heading ``z_rad`` measured at the stream's time ``t_s``; the filtered heading. With ``gate_rad``
        a measurement farther than that from the filtered heading is ignored instead of starting the filter afresh
        (the direction of motion of a rover pushed sideways is not its heading)."""
        r = sigma_rad * sigma_rad
        if self.angle is None:
            if gate_rad is None:
                self.angle, self.rate, self.p, self.t_s = z_rad, 0.0, [r, 0.0, 0.0, 1.0], t_s
            return z_rad
        # predict (constant turn rate, white angular acceleration)
        dt = max(0.0, t_s - self.t_s)
        angle = self.angle + self.rate * dt
        innovation = math.remainder(z_rad - angle, math.tau)
        p00, p01, p10, p11 = self.p
        p00, p01, p10, p11 = (
            p00 + dt * (p10 + p01) + dt * dt * p11 + self.q * dt**4 / 4,
            p01 + dt * p11 + self.q * dt**3 / 2,
            p10 + dt * p11 + self.q * dt**3 / 2,
            p11 + self.q * dt * dt,
        )
        if gate_rad is None:
            nis = min(innovation * innovation / (r + p00), SCATTER_CAP * SCATTER_CAP)
            self.scatter += (nis - self.scatter) / SCATTER_FRAMES
            r *= min(max(self.scatter, 1.0), SCATTER_MAX * SCATTER_MAX)
        elif abs(innovation) > gate_rad:
            return self.angle
        if abs(innovation) > HEADING_RESET_RAD:
            self.angle, self.rate, self.p, self.t_s = z_rad, 0.0, [r, 0.0, 0.0, 1.0], t_s
            return z_rad
        # update
        s = p00 + r
        k0, k1 = p00 / s, p10 / s
        self.angle = math.remainder(angle + k0 * innovation, math.tau)
        self.rate += k1 * innovation
        self.p = [(1 - k0) * p00, (1 - k0) * p01, p10 - k1 * p00, p11 - k1 * p01]
        self.t_s = t_s
        return self.angle

    def reset(self) -> None:
        self.angle = None


MOTION_HEADING_SIGMA_RAD = math.radians(5.0)  # the direction of motion as a heading at 6-20 cm/s: a few degrees
MOTION_HEADING_GATE_RAD = math.radians(30.0)  # farther off, the rover is not driving along its axis (pushed, skidding)


def one_colour_heading(
    heading: HeadingFilter,
    axis_rad: float | None,
    coherence: float,
    velocity_cm_s: tuple[float, float] | None,
    last_heading_rad: float | None,
    min_speed_cm_s: float,
    t_s: float,
    marker_px: float = math.inf,
    motion_sigma_rad: float = 0.0,
) -> float | None:
    """A one-colour marker's heading at the stream's time ``t_s``: its long axis ``axis_rad`` (None for a square
    marker) checked against the motion (:func:`checked_axis`), pointed the way the rover drives or kept from the last
    heading (:func:`axis_heading`), through the rover's ``heading`` filter with the scatter of its source (for edges,
    by the marker's size in the image, ``marker_px``), and the direction of motion as a second measurement while the
    rover drives (one frame's axis can be 10-20 deg off), with the scatter its filter gives it (``motion_sigma_rad``,
    :meth:`ConstantVelocityFilter.direction_sigma_rad`; :data:`MOTION_HEADING_SIGMA_RAD` at least); None (and the
    filter reset) when there is nothing to tell it by."""
    axis = None if axis_rad is None else checked_axis(axis_rad, coherence, velocity_cm_s)
    theta = axis_heading(axis, velocity_cm_s, last_heading_rad, min_speed_cm_s)
    if theta is None:
        heading.reset()
        return None
    theta = heading.update(theta, heading_sigma_rad(coherence if axis is not None else 0.0, marker_px), t_s)
    if axis is not None and velocity_cm_s is not None and math.hypot(*velocity_cm_s) >= MOTION_AXIS_MIN_SPEED_CM_S:
        motion = math.atan2(velocity_cm_s[1], velocity_cm_s[0])
        sigma = max(MOTION_HEADING_SIGMA_RAD, motion_sigma_rad)
        theta = heading.update(motion, sigma, t_s, MOTION_HEADING_GATE_RAD)
    return theta
