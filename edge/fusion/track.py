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


@dataclass
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

    def copy(self) -> CvState:
        return CvState(**self.__dict__)

    @property
    def velocity(self) -> tuple[float, float] | None:
        return (self.vx, self.vy) if self.updates >= 2 else None

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
        a, b, d = self.pxx + rxx, self.pxy + rxy, self.pyy + ryy
        det = a * d - b * b
        nis = (d * nx * nx - 2.0 * b * nx * ny + a * ny * ny) / det
        if nis > fade_nis:  # a manoeuvre: trust the prediction less for this step, follow at once
            f = min(nis / fade_nis, 100.0)
            for name in ("pxx", "pxy", "pyy", "pxu", "pxv", "pyu", "pyv", "puu", "puv", "pvv"):
                setattr(self, name, getattr(self, name) * f)
            a, b, d = self.pxx + rxx, self.pxy + rxy, self.pyy + ryy
            det = a * d - b * b
        ia, ib, id_ = d / det, -b / det, a / det  # S^-1
        # K = P[:, (x, y)] S^-1, one row per state component
        rows = (
            (self.pxx, self.pxy),
            (self.pxy, self.pyy),
            (self.pxu, self.pyu),
            (self.pxv, self.pyv),
        )
        k = [(c1 * ia + c2 * ib, c1 * ib + c2 * id_) for c1, c2 in rows]
        self.x += k[0][0] * nx + k[0][1] * ny
        self.y += k[1][0] * nx + k[1][1] * ny
        self.vx += k[2][0] * nx + k[2][1] * ny
        self.vy += k[3][0] * nx + k[3][1] * ny
        # P -= K P[(x, y), :]: entry (i, j) loses K_i1 P_xj + K_i2 P_yj
        (cx0, cy0), (cx1, cy1), (cx2, cy2), (cx3, cy3) = rows

        def drop(i: int, cxj: float, cyj: float) -> float:
            return k[i][0] * cxj + k[i][1] * cyj

        self.pxx -= drop(0, cx0, cy0)
        self.pxy -= drop(0, cx1, cy1)
        self.pyy -= drop(1, cx1, cy1)
        self.pxu -= drop(0, cx2, cy2)
        self.pxv -= drop(0, cx3, cy3)
        self.pyu -= drop(1, cx2, cy2)
        self.pyv -= drop(1, cx3, cy3)
        self.puu -= drop(2, cx2, cy2)
        self.puv -= drop(2, cx3, cy3)
        self.pvv -= drop(3, cx3, cy3)
        self.updates += 1
