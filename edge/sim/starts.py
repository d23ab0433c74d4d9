"""Where the closed-loop experiments start: random layouts for the formations, scripted paths for the trajectories."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.errors import ConfigError, SimulationError
from edge.sim.targets import PAPER_AREA, AreaCm
from edge.sim.world import Plan, Pose


def random_layout(
    n: int,
    rng: np.random.Generator,
    min_gap_cm: float = 150.0,
    margin_cm: float = 40.0,
    tries: int = 10000,
    area_cm: AreaCm = PAPER_AREA,
) -> list[Pose]:
    """``n`` starts uniformly in the working area ``area_cm`` (x0, y0, x1, y1: the paper's by default; the wide
    arena's for a lab of several cameras), ``margin_cm`` from its edge, pairwise at least ``min_gap_cm`` apart, with
    random headings. All ``n`` are drawn at once and redrawn until they are apart; when that keeps failing (a crowded
    area), they are placed one by one, each where it is clear of those already placed."""
    x0, y0, x1, y1 = area_cm
    lo = np.array([x0 + margin_cm, y0 + margin_cm])
    hi = np.array([x1 - margin_cm, y1 - margin_cm])
    for _ in range(tries if n <= 6 else 200):
        xy = np.column_stack([rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n)])
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        d[np.diag_indices(n)] = np.inf
        if n < 2 or d.min() >= min_gap_cm:
            headings = rng.uniform(-math.pi, math.pi, n)
            return [Pose(float(x), float(y), float(h)) for (x, y), h in zip(xy, headings, strict=True)]
    for _ in range(200):
        placed: list[NDArray[np.float64]] = []
        for _ in range(n):
            for _ in range(500):
                p = rng.uniform(lo, hi)
                if all(math.hypot(*(p - q)) >= min_gap_cm for q in placed):
                    placed.append(p)
                    break
            else:
                break
        if len(placed) == n:
            headings = rng.uniform(-math.pi, math.pi, n)
            return [Pose(float(p[0]), float(p[1]), float(h)) for p, h in zip(placed, headings, strict=True)]
    raise SimulationError(f"no layout of {n} rovers {min_gap_cm:g} cm apart fits in the working area")


def trajectory_plans(kind: str, n: int, rng: np.random.Generator) -> list[Plan]:
    """Scripted paths of the paper's trajectory tests: ``circle`` (Figs. 33-36: each rover 1.75 laps round its own
    circle) and ``diagonal`` (Fig. 37-38: from near (0, 0) towards (391.5, 549.5), side by side)."""
    from edge.sim.trajectories import circle, diagonal

    if kind == "circle":
        centres = [(110.0, 150.0), (280.0, 280.0), (110.0, 410.0), (280.0, 110.0), (280.0, 450.0), (110.0, 280.0)]
        if n > len(centres):
            raise ConfigError(f"the circle test has room for {len(centres)} rovers, got {n}")
        return [
            circle(
                (cx + float(rng.uniform(-10, 10)), cy + float(rng.uniform(-10, 10))),
                float(rng.uniform(55.0, 65.0)),
                laps=1.75,
                speed_cm_s=float(rng.uniform(18.0, 24.0)),
                start_angle_rad=float(rng.uniform(0, 2 * math.pi)),
                ccw=bool(k % 2 == 0),
            )
            for k, (cx, cy) in enumerate(centres[:n])
        ]
    if kind == "diagonal":
        if n > 5:
            raise ConfigError(f"the diagonal test has room for 5 rovers, got {n}")
        length = math.hypot(AREA_WIDTH_CM, AREA_LENGTH_CM)
        ex, ey = AREA_WIDTH_CM / length, AREA_LENGTH_CM / length
        nx, ny = -ey, ex  # across the diagonal
        margin = 30.0
        plans = []
        for k in range(n):
            off = (k - (n - 1) / 2) * 45.0  # 45 cm lanes: the 17.2 cm bodies never meet
            cx, cy = AREA_WIDTH_CM / 2 + off * nx, AREA_LENGTH_CM / 2 + off * ny
            # the stretch of this lane inside the area less the margin
            lo, hi = -math.inf, math.inf
            for c, e, size in ((cx, ex, AREA_WIDTH_CM), (cy, ey, AREA_LENGTH_CM)):
                a, b = (margin - c) / e, (size - margin - c) / e
                lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
            plans.append(
                diagonal(
                    (cx + lo * ex, cy + lo * ey),
                    (cx + hi * ex, cy + hi * ey),
                    speed_cm_s=float(rng.uniform(22.0, 28.0)),
                    wait_before_s=1.0 + 0.5 * k,
                )
            )
        return plans
    raise ConfigError(f"unknown trajectory {kind!r}: use circle or diagonal")
