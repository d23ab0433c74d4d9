"""The calibration the tracker uses at run time, and its versioned JSON file.

:class:`Calibration` maps measured pixels to world cm on the marker plane: undistort the points (when intrinsics
are known), then the inverse plane homography. Vectorised; about a microsecond per point. Whole frames are never
warped (the paper spends 91.2 ms per frame on that, Table IV).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from edge.calibration.homography import apply_homography, homography_w
from edge.calibration.lens import Intrinsics
from edge.camera import Distortion, ImageSide, Matrix3x3, PinholeCamera, Vector3, pose_problem
from edge.errors import CalibrationError, describe_validation

FloatArray = NDArray[np.float64]

KIND = "edge-ips/calibration"
VERSION = 1
MAX_CONDITION = 1e6  # of the homography between area and image both scaled to about [-1, 1]; real views: < 100


def _conditioning(g: FloatArray, area_cm: tuple[float, float, float, float], size: tuple[int, int]) -> float:
    x0, y0, x1, y1 = area_cm
    sw = 2.0 / max(x1 - x0, y1 - y0)
    t_world = np.array([[sw, 0.0, -sw * (x0 + x1) / 2.0], [0.0, sw, -sw * (y0 + y1) / 2.0], [0.0, 0.0, 1.0]])
    sp = 2.0 / max(size)
    t_px = np.array([[sp, 0.0, -sp * size[0] / 2.0], [0.0, sp, -sp * size[1] / 2.0], [0.0, 0.0, 1.0]])
    gn = t_px @ g @ np.linalg.inv(t_world)
    with np.errstate(all="ignore"):
        c = float(np.linalg.cond(gn))
    return c if np.isfinite(c) else float("inf")


@dataclass(frozen=True)
class Calibration:
    """Image -> world mapping for one camera, one image size and one plane height.

    ``homography_world_to_px``: (3, 3) world ``(x, y, 1)`` cm on the plane ``z = plane_height_cm`` -> ideal
    (undistorted) pixels. ``intrinsics``: when known, measured pixels are undistorted first. ``camera``: the full
    camera (pose and intrinsics) when the calibration recovered it (ArUco), which allows :meth:`at_height`.
    ``area_cm``: ``(x0, y0, x1, y1)`` of the working area (for overlays and statistics).
    """

    homography_world_to_px: FloatArray
    width_px: int
    height_px: int
    plane_height_cm: float
    area_cm: tuple[float, float, float, float]
    intrinsics: Intrinsics | None = None
    camera: PinholeCamera | None = None
    homography_px_to_world: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        g = np.asarray(self.homography_world_to_px, dtype=np.float64)
        if g.shape != (3, 3):
            raise CalibrationError(f"the homography must be 3x3, got shape {g.shape}")
        if not np.all(np.isfinite(g)):
            raise CalibrationError("degenerate mapping: the homography has non-finite entries")
        scale = float(np.max(np.abs(g)))
        if scale == 0.0:
            raise CalibrationError("degenerate mapping: the homography is all zeros")
        g = g / scale  # a homography is defined up to scale: 1e-300 or 1e300 entries must not under- or overflow
        x0, y0, x1, y1 = self.area_cm
        if not (x1 > x0 and y1 > y0):
            raise CalibrationError(f"invalid working area {self.area_cm}: need x0 < x1 and y0 < y1")
        if _conditioning(g, self.area_cm, (self.width_px, self.height_px)) > MAX_CONDITION:
            raise CalibrationError(
                "degenerate mapping: the homography is (nearly) singular, it maps the plane to a line"
            )
        centre = np.array([[(x0 + x1) / 2.0, (y0 + y1) / 2.0]])
        if homography_w(g, centre)[0] < 0:  # sign convention: w > 0 in front of the camera
            g = -g
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
        if np.any(homography_w(g, corners) <= 0):
            raise CalibrationError("degenerate mapping: part of the working area maps behind the camera")
        if self.width_px <= 0 or self.height_px <= 0:
            raise CalibrationError(f"invalid image size {self.width_px}x{self.height_px}")
        object.__setattr__(self, "homography_world_to_px", g)
        object.__setattr__(self, "homography_px_to_world", np.linalg.inv(g))

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels of the images this calibration is for."""
        return (self.width_px, self.height_px)

    def pixel_to_world(self, uv_px: FloatArray) -> FloatArray:
        """(N, 2) measured pixels -> (N, 2) world ``x, y`` cm on the marker plane; NaN where the ray misses it."""
        uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
        ideal = self.intrinsics.undistort_px(uv) if self.intrinsics is not None else uv
        q = ideal @ self.homography_px_to_world[:, :2].T + self.homography_px_to_world[:, 2]
        w = q[:, 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = np.where(w > 0, q[:, :2] / w, np.nan)
        return np.asarray(xy)

    def world_to_pixel(self, xy_world_cm: FloatArray) -> FloatArray:
        """(N, 2) world ``x, y`` cm on the marker plane -> (N, 2) pixels as the camera shows them (distorted)."""
        ideal = apply_homography(self.homography_world_to_px, np.asarray(xy_world_cm, dtype=np.float64))
        return self.intrinsics.distort_px(ideal) if self.intrinsics is not None else ideal

    def at_height(self, z_cm: float) -> Calibration:
        """The same camera mapped onto another plane (needs the camera pose: ArUco calibrations have it)."""
        if self.camera is None:
            raise CalibrationError(
                "this calibration has no camera pose (point-pair calibrations hold only for the plane they were "
                f"surveyed on, z = {self.plane_height_cm:g} cm); calibrate with ArUco markers to change height"
            )
        return Calibration(
            self.camera.plane_homography(z_cm),
            self.width_px,
            self.height_px,
            float(z_cm),
            self.area_cm,
            self.intrinsics,
            self.camera,
        )


# -- the file ------------------------------------------------------------------------------------------------------
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class IntrinsicsRecord(_Strict):
    camera_matrix: Matrix3x3
    dist_coeffs: Distortion
    rms_px: float | None = None


class PoseRecord(_Strict):
    rvec: Vector3
    tvec: Vector3


class FitRecord(_Strict):
    """Fit statistics. LOO errors (each point predicted by a fit without it) are the honest accuracy figures."""

    n_points: int
    n_used: int
    sigma_px: float | None = None
    residual_mean_cm: float | None = None
    residual_max_cm: float | None = None
    loo_mean_cm: float | None = None
    loo_max_cm: float | None = None
    loo_rms_cm: float | None = None
    error_map_mean_cm: float | None = None
    error_map_max_cm: float | None = None
    reprojection_rms_px: float | None = None
    notes: list[str] = Field(default_factory=list)


class PointRecord(_Strict):
    row: int
    u: float
    v: float
    x: float
    y: float
    used: bool
    residual_px: float
    error_cm: float
    loo_error_cm: float | None = None


class RejectedRecord(_Strict):
    row: int
    line: int
    u: float
    v: float
    x: float
    y: float
    loo_residual_px: float
    score: float
    error_cm: float


class CalibrationFile(_Strict):
    """On-disk calibration, ``kind`` ``edge-ips/calibration``, ``version`` 1."""

    kind: Literal["edge-ips/calibration"] = "edge-ips/calibration"
    version: Literal[1] = 1
    method: Literal["points", "aruco", "camera"]
    created: str = Field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))
    source: str = ""
    image_width_px: ImageSide
    image_height_px: ImageSide
    plane_height_cm: float = Field(ge=-1000.0, le=1000.0)
    area_cm: tuple[float, float, float, float]
    homography_world_to_px: Matrix3x3
    intrinsics: IntrinsicsRecord | None = None
    camera_pose: PoseRecord | None = None
    fit: FitRecord | None = None
    points: list[PointRecord] = Field(default_factory=list)
    rejected: list[RejectedRecord] = Field(default_factory=list)

    def to_calibration(self) -> Calibration:
        intr = None
        if self.intrinsics is not None:
            try:
                intr = Intrinsics(
                    np.asarray(self.intrinsics.camera_matrix, dtype=np.float64),
                    np.asarray(self.intrinsics.dist_coeffs, dtype=np.float64),
                    self.image_width_px,
                    self.image_height_px,
                )
            except CalibrationError as exc:
                raise CalibrationError(f"intrinsics: {exc}") from None
        cam = None
        if self.camera_pose is not None:
            if intr is None:
                raise CalibrationError("a camera pose needs intrinsics in the same file")
            problem = pose_problem(np.asarray(self.camera_pose.rvec), np.asarray(self.camera_pose.tvec))
            if problem is not None:
                raise CalibrationError(f"camera_pose.{problem}")
            try:
                cam = PinholeCamera(
                    intr.camera_matrix,
                    intr.dist_coeffs,
                    np.asarray(self.camera_pose.rvec),
                    np.asarray(self.camera_pose.tvec),
                    self.image_width_px,
                    self.image_height_px,
                )
            except CalibrationError as exc:
                raise CalibrationError(f"camera_pose: {exc}") from None
        return Calibration(
            np.asarray(self.homography_world_to_px, dtype=np.float64),
            self.image_width_px,
            self.image_height_px,
            self.plane_height_cm,
            self.area_cm,
            intr,
            cam,
        )


def calibration_record(
    cal: Calibration, *, method: Literal["points", "aruco", "camera"], **extra: Any
) -> CalibrationFile:
    """The file form of ``cal``; ``extra`` fills ``source``, ``fit``, ``points``, ``rejected``, ``intrinsics``."""
    intr = extra.pop("intrinsics", None)
    if intr is None and cal.intrinsics is not None:
        intr = IntrinsicsRecord(
            camera_matrix=cal.intrinsics.camera_matrix.tolist(), dist_coeffs=cal.intrinsics.dist_coeffs.tolist()
        )
    pose = None
    if cal.camera is not None:
        pose = PoseRecord(rvec=cal.camera.rvec.tolist(), tvec=cal.camera.tvec.tolist())
    return CalibrationFile(
        method=method,
        image_width_px=cal.width_px,
        image_height_px=cal.height_px,
        plane_height_cm=cal.plane_height_cm,
        area_cm=cal.area_cm,
        homography_world_to_px=cal.homography_world_to_px.tolist(),
        intrinsics=intr,
        camera_pose=pose,
        **extra,
    )


def save_calibration(cal: Calibration | CalibrationFile, path: Path) -> None:
    """Write a calibration file (a bare :class:`Calibration` is saved without fit statistics)."""
    record = (
        cal
        if isinstance(cal, CalibrationFile)
        else calibration_record(cal, method="camera" if cal.camera else "points")
    )
    try:
        path.write_text(record.model_dump_json(indent=2) + "\n")
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot write calibration file ({exc.strerror or exc})") from exc


def read_calibration_file(path: Path) -> CalibrationFile:
    """Read and validate a calibration file; every failure is a :class:`CalibrationError` naming what is wrong."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read calibration file ({exc.strerror or exc})") from exc
    try:
        data = json.loads(raw)
    except UnicodeDecodeError:
        raise CalibrationError(f"{path}: not a calibration file (not UTF-8 text)") from None
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path}: malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: not a calibration file (expected a JSON object)")
    if data.get("kind") != KIND:
        raise CalibrationError(
            f"{path}: not an edge-ips calibration file (kind is {data.get('kind')!r}, expected {KIND!r})"
        )
    version = data.get("version")
    if version != VERSION:
        raise CalibrationError(
            f"{path}: unknown calibration file version {version!r} (this edge-ips reads version {VERSION}); "
            "re-run edge-ips calibrate"
        )
    try:
        return CalibrationFile.model_validate(data)
    except ValidationError as exc:
        raise CalibrationError(f"{path}: invalid calibration file at {describe_validation(exc)}") from None


def load_calibration(path: Path, expected_size: tuple[int, int] | None = None) -> Calibration:
    """Load the runtime :class:`Calibration` from a file, checking it is for images of ``expected_size`` (w, h)."""
    record = read_calibration_file(path)
    try:
        cal = record.to_calibration()
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None
    if expected_size is not None and tuple(expected_size) != cal.image_size:
        w, h = expected_size
        raise CalibrationError(
            f"{path}: calibration is for {cal.width_px}x{cal.height_px} images but the camera delivers {w}x{h}; "
            "calibrate at this resolution"
        )
    return cal
