"""One rover's fused state: a constant-velocity Kalman filter written out in scalars (pure, no numpy per step).

The same model as :class:`edge.filtering.ConstantVelocityFilter` (state ``x, y, vx, vy``, white-noise
acceleration, a fading step for manoeuvres), without its spike logic: the fuser gates detections itself, by
position and by time. Written out because the fuser runs it for every rover in every board's frame (6000 updates
a second for 50 rovers seen twice at 30 frames/s): scalar arithmetic on a symmetric 4 x 4 covariance is several
times faster than numpy on arrays this small.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from edge.filtering import CLEAR_VELOCITY_SIGMAS, clear_velocity


@dataclass(slots=True)
class CvState:
    """State and covariance (the 10 distinct entries of the symmetric 4 x 4), cm and s."""

    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    pxx: float = 1.0
    pxy: float = 0.0
    pyy: float = 1.0
    pxu: float = 0.0  # cov(x, vx)
    pxv: float = 0.0  # cov(x, vy)
    pyu: float = 0.0  # cov(y, vx)
    pyv: float = 0.0  # cov(y, vy)
    puu: float = 2500.0  # var(vx)
    puv: float = 0.0
    pvv: float = 2500.0  # var(vy)
    updates: int = 1

    @classmethod
    def start(cls, x: float, y: float, rxx: float, rxy: float, ryy: float, speed_sigma_cm_s: float) -> CvState:
        v = speed_sigma_cm_s * speed_sigma_cm_s
        return cls(x, y, pxx=rxx, pxy=rxy, pyy=ryy, puu=v, pvv=v)

    def snapshot(self) -> tuple[float, ...]:
        """The state as an immutable tuple (cheap to keep after every update; :meth:`restore` makes it a filter)."""
        return (
            self.x, self.y, self.vx, self.vy, self.pxx, self.pxy, self.pyy, self.pxu, self.pxv, self.pyu, self.pyv,
            self.puu, self.puv, self.pvv, self.updates,
        )  # fmt: skip

    @classmethod
    def restore(cls, snapshot: tuple[float, ...]) -> CvState:
        x, y, vx, vy, pxx, pxy, pyy, pxu, pxv, pyu, pyv, puu, puv, pvv, updates = snapshot
        return cls(x, y, vx, vy, pxx, pxy, pyy, pxu, pxv, pyu, pyv, puu, puv, pvv, int(updates))

    @property
    def velocity(self) -> tuple[float, float] | None:
        return (self.vx, self.vy) if self.updates >= 2 else None

    def clear_velocity(self, sigmas: float = CLEAR_VELOCITY_SIGMAS) -> tuple[float, float] | None:
        """The velocity when it is clear of its own noise (``edge.filtering.clear_velocity``), else None."""
        return clear_velocity((self.vx, self.vy), (self.puu, self.puv, self.pvv), self.updates, sigmas)

    def predict(self, dt: float, accel_sigma_cm_s2: float) -> None:
        if dt <= 0.0:
            return
        q = accel_sigma_cm_s2 * accel_sigma_cm_s2
        dt2 = dt * dt
        self.x += self.vx * dt
        self.y += self.vy * dt
        pxu, pxv, pyu, pyv = self.pxu, self.pxv, self.pyu, self.pyv
        self.pxx += 2.0 * dt * pxu + dt2 * self.puu + q * dt2 * dt2 / 4.0
        self.pxy += dt * (pxv + pyu) + dt2 * self.puv
        self.pyy += 2.0 * dt * pyv + dt2 * self.pvv + q * dt2 * dt2 / 4.0
        self.pxu = pxu + dt * self.puu + q * dt2 * dt / 2.0
        self.pxv = pxv + dt * self.puv
        self.pyu = pyu + dt * self.puv
        self.pyv = pyv + dt * self.pvv + q * dt2 * dt / 2.0
        self.puu += q * dt2
        self.pvv += q * dt2

    def nis(self, zx: float, zy: float, rxx: float, rxy: float, ryy: float, dt: float = 0.0) -> float:
        """Normalised innovation squared of a measurement ``dt`` after the state (a late one: ``dt`` < 0)."""
        nx = zx - (self.x + self.vx * dt)
        ny = zy - (self.y + self.vy * dt)
        a, b, d = self.pxx + rxx, self.pxy + rxy, self.pyy + ryy
        det = a * d - b * b
        if det <= 0.0:
            return math.inf
        return (d * nx * nx - 2.0 * b * nx * ny + a * ny * ny) / det

    def update(self, zx: float, zy: float, rxx: float, rxy: float, ryy: float, fade_nis: float) -> None:
        nx, ny = zx - self.x, zy - self.y
        pxx, pxy, pyy, pxu, pxv = self.pxx, self.pxy, self.pyy, self.pxu, self.pxv
        pyu, pyv, puu, puv, pvv = self.pyu, self.pyv, self.puu, self.puv, self.pvv
        a, b, d = pxx + rxx, pxy + rxy, pyy + ryy
        det = a * d - b * b
        nis = (d * nx * nx - 2.0 * b * nx * ny + a * ny * ny) / det
        if nis > fade_nis:  # a manoeuvre: trust the prediction less for this step, follow at once
            f = min(nis / fade_nis, 100.0)
            pxx, pxy, pyy, pxu, pxv = pxx * f, pxy * f, pyy * f, pxu * f, pxv * f
            pyu, pyv, puu, puv, pvv = pyu * f, pyv * f, puu * f, puv * f, pvv * f
            a, b, d = pxx + rxx, pxy + rxy, pyy + ryy
            det = a * d - b * b
        ia, ib, id_ = d / det, -b / det, a / det  # S^-1
        # K = P[:, (x, y)] S^-1, one row per state component (x, y, vx, vy)
        k0x, k0y = pxx * ia + pxy * ib, pxx * ib + pxy * id_
        k1x, k1y = pxy * ia + pyy * ib, pxy * ib + pyy * id_
        k2x, k2y = pxu * ia + pyu * ib, pxu * ib + pyu * id_
        k3x, k3y = pxv * ia + pyv * ib, pxv * ib + pyv * id_
        self.x += k0x * nx + k0y * ny
        self.y += k1x * nx + k1y * ny
        self.vx += k2x * nx + k2y * ny
        self.vy += k3x * nx + k3y * ny
        # P -= K P[(x, y), :]: entry (i, j) loses K_i1 P_xj + K_i2 P_yj
        self.pxx = pxx - (k0x * pxx + k0y * pxy)
        self.pxy = pxy - (k0x * pxy + k0y * pyy)
        self.pyy = pyy - (k1x * pxy + k1y * pyy)
        self.pxu = pxu - (k0x * pxu + k0y * pyu)
        self.pxv = pxv - (k0x * pxv + k0y * pyv)
        self.pyu = pyu - (k1x * pxu + k1y * pyu)
        self.pyv = pyv - (k1x * pxv + k1y * pyv)
        self.puu = puu - (k2x * pxu + k2y * pyu)
        self.puv = puv - (k2x * pxv + k2y * pyv)
        self.pvv = pvv - (k3x * pxv + k3y * pyv)
        self.updates += 1
