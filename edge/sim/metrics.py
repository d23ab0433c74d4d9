"""Formation metrics, pure numpy: how well a fleet holds a line, a rendezvous or a triangle, and how close it came.

Positions are marker centres in world cm (the simulator's ground truth, or what the edge measured). A formation's
bar:

* **line** (paper Figs. 27-28, "vertical line"): every rover within ``tol_cm`` of the common vertical line (the
  mean x of the rovers), and every gap between neighbours along y within ``tol_cm`` of the commanded spacing;
* **rendezvous** (Figs. 29-30): all centres inside a circle of ``zone_cm`` diameter (smallest enclosing circle);
* **triangle** (Figs. 31-32): every side ``side_cm +- tol_cm`` (three rovers; more rovers: the regular polygon's
  sides between neighbours round the centroid).

Bodies touch when their footprints (``length_cm`` x ``width_cm`` boxes round the marker centre, along the heading)
overlap: :func:`min_body_gap_cm` is the exact distance between the boxes (negative: the depth they overlap). The
firmware's own safety distance works on circles (``geometry.body_radius_cm``), which is more conservative.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

FORMATIONS = ("line", "rendezvous", "triangle")


@dataclass(frozen=True)
class Bar:
    """The target and tolerance of one formation."""

    kind: str
    spacing_cm: float = 60.0  # line
    side_cm: float = 100.0  # triangle
    tol_cm: float = 3.0  # line displacement and spacing, triangle sides
    zone_cm: float = 40.0  # rendezvous zone diameter
    within_frames: int = 240  # converged by this frame


def line_errors(xy_cm: FloatArray) -> tuple[float, float, FloatArray]:
    """(largest distance from the common vertical line, largest spacing, gaps between neighbours along y).

    ``xy_cm``: (N, 2). The common line is the mean x; gaps are between rovers sorted by y.
    """
    x = xy_cm[:, 0]
    displacement = float(np.max(np.abs(x - x.mean())))
    ys = np.sort(xy_cm[:, 1])
    gaps = np.diff(ys)
    return displacement, float(gaps.max()) if gaps.size else 0.0, gaps


def enclosing_diameter_cm(xy_cm: FloatArray) -> float:
    """Diameter of the smallest circle containing every point, (N, 2) -> cm (exact, by trying every circle through
    two or three of the points: fine for a fleet of a dozen)."""
    pts = np.asarray(xy_cm, dtype=np.float64)
    n = len(pts)
    if n == 0:
        return 0.0
    if n == 1:
        return 0.0
    best = math.inf
    for i, j in itertools.combinations(range(n), 2):
        c = 0.5 * (pts[i] + pts[j])
        r = 0.5 * float(np.hypot(*(pts[i] - pts[j])))
        if r < best and _covers(pts, c, r):
            best = r
    for i, j, k in itertools.combinations(range(n), 3):
        circle = _circumcircle(pts[i], pts[j], pts[k])
        if circle is not None and circle[1] < best and _covers(pts, circle[0], circle[1]):
            best = circle[1]
    return 2.0 * best


def _covers(pts: FloatArray, centre: FloatArray, r: float) -> bool:
    return bool(np.all(np.hypot(*(pts - centre).T) <= r + 1e-9))


def _circumcircle(a: FloatArray, b: FloatArray, c: FloatArray) -> tuple[FloatArray, float] | None:
    d = 2.0 * (a[0] * (b[1] - c[1]) + b[0] * (c[1] - a[1]) + c[0] * (a[1] - b[1]))
    if abs(d) < 1e-12:
        return None
    sa, sb, sc = a @ a, b @ b, c @ c
    ux = (sa * (b[1] - c[1]) + sb * (c[1] - a[1]) + sc * (a[1] - b[1])) / d
    uy = (sa * (c[0] - b[0]) + sb * (a[0] - c[0]) + sc * (b[0] - a[0])) / d
    centre = np.array([ux, uy])
    return centre, float(np.hypot(*(a - centre)))


def polygon_sides_cm(xy_cm: FloatArray) -> FloatArray:
    """Sides of the polygon the rovers make, taken in angular order round their centroid: (N,) cm (N >= 3)."""
    pts = np.asarray(xy_cm, dtype=np.float64)
    rel = pts - pts.mean(axis=0)
    order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))
    ring = pts[order]
    return np.asarray(np.hypot(*(np.roll(ring, -1, axis=0) - ring).T), dtype=np.float64)


def formation_error(bar: Bar, xy_cm: FloatArray) -> float:
    """How far the fleet is from the bar, in the bar's own unit: <= 0 means the bar holds.

    line: max(displacement, max |gap - spacing|) - tol; rendezvous: diameter - zone; triangle: max |side - side| -
    tol.
    """
    if bar.kind == "line":
        displacement, _, gaps = line_errors(xy_cm)
        spacing = float(np.max(np.abs(gaps - bar.spacing_cm))) if gaps.size else 0.0
        return max(displacement, spacing) - bar.tol_cm
    if bar.kind == "rendezvous":
        return enclosing_diameter_cm(xy_cm) - bar.zone_cm
    if bar.kind == "triangle":
        return float(np.max(np.abs(polygon_sides_cm(xy_cm) - bar.side_cm))) - bar.tol_cm
    raise ValueError(f"unknown formation {bar.kind!r}")


def converged_frame(errors: Sequence[float] | FloatArray) -> int | None:
    """First frame from which the bar holds (error <= 0) to the end of the run; None if it does not hold at the end."""
    e = np.asarray(errors, dtype=np.float64)
    if e.size == 0 or e[-1] > 0:
        return None
    bad = np.flatnonzero(e > 0)
    return int(bad[-1] + 1) if bad.size else 0


# -- bodies ----------------------------------------------------------------------------------------------------
def box_corners_cm(x_cm: float, y_cm: float, theta_rad: float, length_cm: float, width_cm: float) -> FloatArray:
    """(4, 2) corners of a box centred at (x, y), ``length_cm`` along the heading, counter-clockwise."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    hl, hw = 0.5 * length_cm, 0.5 * width_cm
    local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    rot = np.array([[c, -s], [s, c]])
    return np.asarray(local @ rot.T + np.array([x_cm, y_cm]), dtype=np.float64)


def box_gap_cm(a: FloatArray, b: FloatArray) -> float:
    """Distance between two convex quadrilaterals (4, 2); negative: they overlap, by the separating-axis depth."""
    depth = math.inf
    for poly in (a, b):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            axis = np.array([-edge[1], edge[0]]) / math.hypot(*edge)
            pa, pb = a @ axis, b @ axis
            sep = max(pb.min() - pa.max(), pa.min() - pb.max())
            if sep > 0:
                return _polygon_distance(a, b)
            depth = min(depth, -sep)
    return -depth


def _polygon_distance(a: FloatArray, b: FloatArray) -> float:
    """Distance between two disjoint convex polygons: the closest vertex-edge pair, both ways."""
    best = math.inf
    for p, q in ((a, b), (b, a)):
        for k in range(len(q)):
            s0, s1 = q[k], q[(k + 1) % len(q)]
            d = s1 - s0
            t = np.clip(((p - s0) @ d) / (d @ d), 0.0, 1.0)
            closest = s0 + t[:, None] * d
            best = min(best, float(np.min(np.hypot(*(p - closest).T))))
    return best


def min_body_gap_cm(poses: FloatArray, length_cm: float, width_cm: float) -> float:
    """Smallest gap between any two bodies, (N, 3) poses (x, y, theta) -> cm (negative: overlap); inf for one."""
    n = len(poses)
    if n < 2:
        return math.inf
    boxes = [box_corners_cm(float(p[0]), float(p[1]), float(p[2]), length_cm, width_cm) for p in poses]
    return min(box_gap_cm(boxes[i], boxes[j]) for i, j in itertools.combinations(range(n), 2))


def min_centre_distance_cm(xy_cm: FloatArray) -> float:
    """Smallest distance between two centres, (N, 2) -> cm; inf for one rover."""
    pts = np.asarray(xy_cm, dtype=np.float64)
    if len(pts) < 2:
        return math.inf
    d = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
    d[np.diag_indices(len(pts))] = np.inf
    return float(d.min())


def error_stats_cm(errors_cm: Sequence[float] | FloatArray) -> dict[str, float | int | None]:
    """mean, median, p95, max of a list of distances (None when empty), and how many."""
    e = np.asarray(errors_cm, dtype=np.float64)
    if e.size == 0:
        return {"n": 0, "mean": None, "median": None, "p95": None, "max": None}
    return {
        "n": int(e.size),
        "mean": float(e.mean()),
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
        "max": float(e.max()),
    }
