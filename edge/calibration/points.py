"""Point-pair calibration (paper section III.A, "point coordinates calibration"), made robust and honest.

Input: surveyed points on the marker plane, each known in pixels (``u, v``) and in world cm (``x, y``).
Output: the plane mapping, every point's residual, the points rejected as mis-measured (reported, never silently
absorbed) and leave-one-out (LOO) errors in cm, which are the honest accuracy figures: each point is predicted by
a mapping fitted without it.

Outlier test: each point's LOO prediction residual in pixels, whitened by its prediction covariance
``sigma^2 (I + J_i C_-i J_i^T)`` (far-edge points are extrapolated more and may miss by more), against a robust
noise level (median of the whitened residuals; chi-square with 2 degrees of freedom). The worst point beyond the
threshold is removed and the test repeated, so one gross error cannot hide another.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from edge.calibration.errormap import ErrorMap, predicted_error_map
from edge.calibration.files import (
    Calibration,
    CalibrationFile,
    FitRecord,
    PointRecord,
    RejectedRecord,
    calibration_record,
)
from edge.calibration.homography import PlaneFit, apply_homography, fit_plane
from edge.calibration.lens import Intrinsics
from edge.calibration.tables import parse_table, read_text
from edge.camera import MARKER_HEIGHT_CM
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]

COLUMNS = ("u", "v", "x", "y")
MIN_POINTS = 4
MIN_POINTS_FOR_OUTLIER_TEST = 7  # the LOO fit of 6 points still has 4 redundant coordinates
MAX_POINTS_FOR_LINE_SEARCH = 200
MIN_SIGMA_PX = 0.1  # nobody measures a pixel position better than this; keeps perfect synthetic data sane
FALSE_ALARM_RATE = 0.01  # per calibration, under Gaussian noise
MAX_REJECTED_FRACTION = 0.25
CHI2_2_MEDIAN = 2.0 * math.log(2.0)  # median of a chi-square variable with 2 degrees of freedom


@dataclass(frozen=True)
class PointTable:
    """Point pairs read from a CSV. ``uv_px``, ``xy_world_cm``: (N, 2) float64; ``rows``: (N,) data-row numbers
    (1 = first row after the header); ``lines``: (N,) line numbers in the file."""

    source: str
    uv_px: FloatArray
    xy_world_cm: FloatArray
    rows: NDArray[np.int64]
    lines: NDArray[np.int64]

    def where(self, i: int) -> str:
        return f"{self.source} row {int(self.rows[i])} (line {int(self.lines[i])})"

    def __len__(self) -> int:
        return int(self.uv_px.shape[0])


def point_table(uv_px: FloatArray, xy_world_cm: FloatArray, source: str = "points") -> PointTable:
    """A :class:`PointTable` from arrays (rows numbered from 1, one line of header)."""
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(xy_world_cm, dtype=np.float64).reshape(-1, 2)
    if uv.shape != xy.shape:
        raise CalibrationError(f"{source}: {uv.shape[0]} pixel points but {xy.shape[0]} world points")
    rows = np.arange(1, uv.shape[0] + 1, dtype=np.int64)
    return PointTable(source, uv, xy, rows, rows + 1)


def read_points_csv(path: Path) -> PointTable:
    """Read a ``u,v,x,y`` CSV (header required, any column order, extra columns ignored, ``#`` lines skipped)."""
    return parse_points_csv(read_text(path, "points file"), str(path))


def parse_points_csv(text: str, source: str) -> PointTable:
    table = parse_table(text, source, COLUMNS)
    c = table.columns
    return PointTable(
        source=source,
        uv_px=np.column_stack([c["u"], c["v"]]),
        xy_world_cm=np.column_stack([c["x"], c["y"]]),
        rows=table.rows,
        lines=table.lines,
    )


def write_points_csv(path: Path, uv_px: FloatArray, xy_world_cm: FloatArray) -> None:
    """Write point pairs as a ``u,v,x,y`` CSV (pixels to 1e-3 px, world to 1e-3 cm)."""
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(xy_world_cm, dtype=np.float64).reshape(-1, 2)
    lines = ["u,v,x,y"] + [f"{u:.3f},{v:.3f},{x:.3f},{y:.3f}" for (u, v), (x, y) in zip(uv, xy, strict=True)]
    path.write_text("\n".join(lines) + "\n")


# -- validation ------------------------------------------------------------------------------------------------
def validate_points(table: PointTable, image_size: tuple[int, int] | None) -> None:
    """Raise :class:`CalibrationError` naming the row for: too few, outside the image, duplicate or collinear."""
    n = len(table)
    if n < MIN_POINTS:
        raise CalibrationError(f"{table.source}: need at least {MIN_POINTS} points, found {n}")
    if image_size is not None:
        w, h = image_size
        for i, (u, v) in enumerate(table.uv_px):
            if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
                raise CalibrationError(f"{table.where(i)}: pixel ({u:g}, {v:g}) is outside the {w}x{h} image")
    for what, arr, tol in (("world point", table.xy_world_cm, 1e-6), ("pixel", table.uv_px, 1e-6)):
        _check_duplicates(table, arr, what, tol)
    for what, arr in (("world", table.xy_world_cm), ("pixel", table.uv_px)):
        _check_collinear(table, arr, what)


def _check_duplicates(table: PointTable, arr: FloatArray, what: str, tol: float) -> None:
    order = np.lexsort((arr[:, 1], arr[:, 0]))
    sorted_arr = arr[order]
    same = np.all(np.abs(np.diff(sorted_arr, axis=0)) <= tol, axis=1)
    if np.any(same):
        k = int(np.argmax(same))
        a, b = sorted((int(order[k]), int(order[k + 1])))
        p = arr[b]
        raise CalibrationError(f"{table.where(b)}: duplicate {what} ({p[0]:g}, {p[1]:g}) of row {int(table.rows[a])}")


def _check_collinear(table: PointTable, arr: FloatArray, what: str) -> None:
    """A plane mapping needs 4 points with no 3 on a line: refuse sets with at most one point off a line."""
    n = arr.shape[0]
    centred = arr - arr.mean(axis=0)
    scale = float(np.max(np.linalg.norm(centred, axis=1)))
    tol = 1e-3 * scale
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    if scale == 0.0 or np.all(np.abs(centred @ vt[-1]) <= tol):
        raise CalibrationError(
            f"{table.source}: all {n} {what} points lie on one line; need points spread over the plane"
        )
    if n > MAX_POINTS_FOR_LINE_SEARCH:
        return
    for i in range(n):  # lines through two points: does one hold all points but one?
        d = arr[i + 1 :] - arr[i]
        lengths = np.linalg.norm(d, axis=1)
        for k in np.flatnonzero(lengths > tol):
            direction = d[k] / lengths[k]
            dist = np.abs((arr - arr[i]) @ np.array([-direction[1], direction[0]]))
            off = np.flatnonzero(dist > tol)
            if off.size == 1:
                raise CalibrationError(
                    f"{table.source}: all {what} points but {table.where(int(off[0]))} lie on one line; "
                    "need at least two points off the line"
                )


# -- fitting ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RejectedPoint:
    """A point the outlier test excluded: where it is in the file, and how far off it was."""

    index: int
    row: int
    line: int
    uv_px: tuple[float, float]
    xy_world_cm: tuple[float, float]
    loo_residual_px: float  # predicted-minus-measured distance when fitted without it
    score: float  # whitened LOO residual in units of the robust noise sigma
    error_cm: float  # world distance between its x, y and where the final mapping puts its u, v


@dataclass(frozen=True)
class PointsFit:
    """What fitting the point pairs gave.

    ``plane``: the final fit on the points kept (ideal pixels). ``used``: (N,) bool. ``residual_px``: (N, 2) measured
    minus predicted (ideal) pixels under the final fit, rejected points included. ``residual_cm``: (N,) world distance
    between each point's x, y and its mapped u, v. ``loo_error_cm``: (N,) the same with the point left out of the fit
    (for rejected points: the final fit, which already leaves them out). ``loo_residual_px``: (N,) LOO pixel
    residual norms of the final round.
    """

    table: PointTable
    plane: PlaneFit
    used: NDArray[np.bool_]
    residual_px: FloatArray
    residual_cm: FloatArray
    loo_error_cm: FloatArray | None
    loo_residual_px: FloatArray | None
    sigma_px: float | None
    robust_sigma_px: float | None
    rejected: tuple[RejectedPoint, ...] = field(default=())
    outlier_test: bool = True

    @property
    def n_used(self) -> int:
        return int(np.count_nonzero(self.used))

    def loo_stats_cm(self) -> tuple[float, float, float] | None:
        """(mean, max, rms) of the LOO errors of the points kept, or None when LOO is impossible (< 5 points).
        Points whose neighbours alone are degenerate (NaN) cannot be cross-checked and are left out."""
        if self.loo_error_cm is None:
            return None
        e = self.loo_error_cm[self.used]
        e = e[np.isfinite(e)]
        if e.size == 0:
            return None
        return float(e.mean()), float(e.max()), float(np.sqrt(np.mean(e**2)))


def _loo(world: FloatArray, uv: FloatArray, full: PlaneFit) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Leave-one-out over the points: (N, 2) pixel prediction residuals, (N,) whitened squared residuals for unit
    noise, (N,) world errors in cm."""
    n = world.shape[0]
    resid = np.empty((n, 2))
    d2 = np.empty(n)
    err_cm = np.empty(n)
    j_all = full.param_jacobian_px(world)
    mask = np.ones(n, dtype=bool)
    for i in range(n):
        mask[i] = False
        try:
            part = fit_plane(world[mask], uv[mask])
        except CalibrationError:  # the others alone are degenerate: this point cannot be cross-checked
            mask[i] = True
            resid[i] = np.nan
            d2[i] = np.nan
            err_cm[i] = np.nan
            continue
        mask[i] = True
        pred = apply_homography(part.g, world[i : i + 1])[0]
        resid[i] = uv[i] - pred
        info = np.einsum("nik,nil->kl", j_all[mask & (np.arange(n) != i)], j_all[mask & (np.arange(n) != i)])
        ji = j_all[i]
        p = np.eye(2) + ji @ np.linalg.pinv(info) @ ji.T
        d2[i] = float(resid[i] @ np.linalg.solve(p, resid[i]))
        back = apply_homography(np.linalg.inv(part.g), uv[i : i + 1])[0]
        err_cm[i] = float(np.linalg.norm(back - world[i]))
    return resid, d2, err_cm


def fit_points(
    table: PointTable,
    image_size: tuple[int, int] | None = None,
    intrinsics: Intrinsics | None = None,
    *,
    detect_outliers: bool = True,
) -> PointsFit:
    """Fit the plane mapping to surveyed points, rejecting and reporting mis-measured ones.

    With ``intrinsics`` the measured pixels are undistorted (``cv2.undistortPoints``, P = K) before the fit, and
    the fitted homography maps to ideal pixels.
    """
    validate_points(table, image_size)
    world = table.xy_world_cm
    uv = intrinsics.undistort_px(table.uv_px) if intrinsics is not None else table.uv_px.copy()
    n = len(table)
    used = np.ones(n, dtype=bool)
    rejected: list[RejectedPoint] = []
    plane = _fit_or_explain(table, world, uv)
    loo_resid: FloatArray | None = None
    loo_err: FloatArray | None = None
    robust_sigma: float | None = None
    run_test = detect_outliers and n >= MIN_POINTS_FOR_OUTLIER_TEST
    max_rejected = int(MAX_REJECTED_FRACTION * n)
    if n >= MIN_POINTS + 1:
        while True:
            idx = np.flatnonzero(used)
            resid, d2, err = _loo(world[idx], uv[idx], plane)
            loo_resid, loo_err = resid, err
            if not run_test:
                break
            finite = np.isfinite(d2)
            if not np.any(finite):
                break
            robust_sigma = max(MIN_SIGMA_PX, math.sqrt(float(np.median(d2[finite])) / CHI2_2_MEDIAN))
            threshold = 2.0 * math.log(idx.size / FALSE_ALARM_RATE)  # chi2(2) tail exp(-t/2) = alpha / N
            score2 = np.where(finite, d2, 0.0) / robust_sigma**2
            worst = int(np.argmax(score2))
            if score2[worst] <= threshold:
                break
            i = int(idx[worst])
            if len(rejected) >= max_rejected or idx.size - 1 < MIN_POINTS_FOR_OUTLIER_TEST:
                rows = ", ".join(str(int(table.rows[r.index])) for r in rejected) + (", " if rejected else "")
                raise CalibrationError(
                    f"{table.source}: too many inconsistent points (rows {rows}{int(table.rows[i])} and maybe more); "
                    "check the measurements, the u,v/x,y columns and the plane height"
                )
            used[i] = False
            plane = _fit_or_explain(table, world[used], uv[used])
            rejected.append(
                RejectedPoint(
                    index=i,
                    row=int(table.rows[i]),
                    line=int(table.lines[i]),
                    uv_px=(float(table.uv_px[i, 0]), float(table.uv_px[i, 1])),
                    xy_world_cm=(float(world[i, 0]), float(world[i, 1])),
                    loo_residual_px=float(np.linalg.norm(resid[worst])),
                    score=float(math.sqrt(score2[worst])),
                    error_cm=0.0,
                )
            )
    residual_px = uv - apply_homography(plane.g, world)
    mapped = apply_homography(np.linalg.inv(plane.g), uv)
    residual_cm = np.linalg.norm(mapped - world, axis=1)
    rejected = [replace(r, error_cm=float(residual_cm[r.index])) for r in rejected]
    loo_full: FloatArray | None = None
    loo_px_full: FloatArray | None = None
    if loo_err is not None and loo_resid is not None:
        loo_full = residual_cm.copy()
        loo_full[used] = loo_err
        loo_px_full = np.linalg.norm(residual_px, axis=1)
        loo_px_full[used] = np.linalg.norm(loo_resid, axis=1)
    return PointsFit(
        table=table,
        plane=plane,
        used=used,
        residual_px=residual_px,
        residual_cm=residual_cm,
        loo_error_cm=loo_full,
        loo_residual_px=loo_px_full,
        sigma_px=plane.sigma_px,
        robust_sigma_px=robust_sigma,
        rejected=tuple(rejected),
        outlier_test=run_test,
    )


def _fit_or_explain(table: PointTable, world: FloatArray, uv: FloatArray) -> PlaneFit:
    plane = fit_plane(world, uv)
    cond = np.linalg.cond(plane.information)
    if not np.isfinite(cond) or cond > 1e12:
        raise CalibrationError(f"{table.source}: the points do not determine a plane mapping (nearly collinear layout)")
    return plane


# -- the whole point-pair calibration -------------------------------------------------------------------------------
@dataclass(frozen=True)
class PointsCalibration:
    """The result of :func:`calibrate_points`: runtime calibration, its file record, the fit and the error map."""

    calibration: Calibration
    record: CalibrationFile
    fit: PointsFit
    stats: FitRecord
    error_map: ErrorMap | None


def calibrate_points(
    table: PointTable,
    image_size: tuple[int, int],
    *,
    height_cm: float = MARKER_HEIGHT_CM,
    intrinsics: Intrinsics | None = None,
    area_cm: tuple[float, float, float, float] | None = None,
    detect_outliers: bool = True,
    error_map_step_px: int = 8,
) -> PointsCalibration:
    """Fit, report and package a point-pair calibration. ``area_cm`` defaults to the bounding box of the points
    kept; the error map needs at least 5 points (redundancy to estimate the noise)."""
    if intrinsics is not None and (intrinsics.width_px, intrinsics.height_px) != tuple(image_size):
        raise CalibrationError(
            f"intrinsics are for {intrinsics.width_px}x{intrinsics.height_px} images, "
            f"the points for {image_size[0]}x{image_size[1]}"
        )
    if not math.isfinite(height_cm):
        raise CalibrationError(f"plane height must be a finite number of cm, got {height_cm}")
    fit = fit_points(table, image_size, intrinsics, detect_outliers=detect_outliers)
    if area_cm is None:
        kept = table.xy_world_cm[fit.used]
        lo, hi = kept.min(axis=0), kept.max(axis=0)
        area_cm = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    try:
        cal = Calibration(fit.plane.g, image_size[0], image_size[1], float(height_cm), area_cm, intrinsics)
    except CalibrationError as exc:
        raise CalibrationError(f"{table.source}: {exc}") from None
    emap = None
    notes: list[str] = []
    if fit.sigma_px is not None and fit.sigma_px > 0:
        emap = predicted_error_map(fit.plane, fit.sigma_px, cal, step_px=error_map_step_px)
    else:
        notes.append("no error map: 4 points fit exactly, there is no redundancy to estimate the noise")
    if not fit.outlier_test:
        notes.append(
            f"no outlier test: it needs at least {MIN_POINTS_FOR_OUTLIER_TEST} points"
            if detect_outliers
            else "outlier test switched off"
        )
    loo = fit.loo_stats_cm()
    used_cm = fit.residual_cm[fit.used]
    stats = FitRecord(
        n_points=len(table),
        n_used=fit.n_used,
        sigma_px=fit.sigma_px,
        residual_mean_cm=float(used_cm.mean()),
        residual_max_cm=float(used_cm.max()),
        loo_mean_cm=loo[0] if loo else None,
        loo_max_cm=loo[1] if loo else None,
        loo_rms_cm=loo[2] if loo else None,
        error_map_mean_cm=emap.mean_cm if emap else None,
        error_map_max_cm=emap.max_cm if emap else None,
        notes=notes,
    )
    points = [
        PointRecord(
            row=int(table.rows[i]),
            u=float(table.uv_px[i, 0]),
            v=float(table.uv_px[i, 1]),
            x=float(table.xy_world_cm[i, 0]),
            y=float(table.xy_world_cm[i, 1]),
            used=bool(fit.used[i]),
            residual_px=float(np.linalg.norm(fit.residual_px[i])),
            error_cm=float(fit.residual_cm[i]),
            loo_error_cm=None
            if fit.loo_error_cm is None or not np.isfinite(fit.loo_error_cm[i])
            else float(fit.loo_error_cm[i]),
        )
        for i in range(len(table))
    ]
    rejected = [
        RejectedRecord(
            row=r.row,
            line=r.line,
            u=r.uv_px[0],
            v=r.uv_px[1],
            x=r.xy_world_cm[0],
            y=r.xy_world_cm[1],
            loo_residual_px=r.loo_residual_px,
            score=r.score,
            error_cm=r.error_cm,
        )
        for r in fit.rejected
    ]
    record = calibration_record(cal, method="points", source=table.source, fit=stats, points=points, rejected=rejected)
    return PointsCalibration(cal, record, fit, stats, emap)
