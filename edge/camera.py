"""Pinhole camera model with lens distortion (OpenCV conventions), shared by the simulator and calibration.

World frame: centimetres, origin at the bottom-left corner of the working area (as in the paper's Fig. 1), x along
the 391.5 cm width, y along the 549.5 cm length, z up from the floor. Camera frame: OpenCV (x right, y down,
z forward). ``rvec``/``tvec`` map world points into the camera frame: ``X_cam = R @ X_world + t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from edge.errors import CalibrationError, describe_validation

FloatArray = NDArray[np.float64]

# Shapes of the matrices in calibration, intrinsics and camera files, checked when a file is read (a 3x2 matrix
# or a ragged row is a one-line error naming the file, never a numpy traceback at start-up).
Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Matrix3x3 = Annotated[list[Vector3], Field(min_length=3, max_length=3)]
Distortion = Annotated[list[float], Field(max_length=5, description="k1, k2, p1, p2, k3 (missing ones are 0)")]
ImageSide = Annotated[int, Field(strict=True, gt=0, le=65535)]

# cv2.undistortPoints inverts the lens by fixed-point iteration, which converges slowly where the lens stretches
# the image most: OpenCV's default (5 iterations) leaves ~0.003 px at the corners of a mild barrel lens, and the
# ChArUco tutorial camera's strong pincushion (k3 2.95) still misses a corner by 11 px after 20 iterations and
# 0.009 px after 100. The EPS test stops as soon as a point has converged, so the cap costs nothing elsewhere.
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-9)


MAX_ROTATION_RAD = 2.0 * math.pi  # a rotation vector's length is its angle: every rotation has one within pi
MAX_TRANSLATION_CM = 1e6  # 10 km: no camera above a floor is further from the origin


def pose_problem(rvec: FloatArray, tvec: FloatArray) -> str | None:
    """What makes ``rvec``, ``tvec`` no camera pose, or None: said from the field's name on (``rvec: ...``).

    Finite numbers are not enough: cv2.Rodrigues turns a rotation vector of length 1e308 (or one whose length
    overflows) into a NaN matrix, and every pixel then maps to NaN.
    """
    for name, v, limit, unit in (("rvec", rvec, MAX_ROTATION_RAD, "rad"), ("tvec", tvec, MAX_TRANSLATION_CM, "cm")):
        if v.shape != (3,):
            return f"{name}: expected 3 numbers, got shape {v.shape}"
        if not np.all(np.isfinite(v)):
            return f"{name}: must be finite numbers"
        length = math.hypot(*(float(x) for x in v))  # np.linalg.norm overflows to inf at 1e308
        if not length <= limit:
            return f"{name}: length {length:.3g} {unit} is not a camera pose (at most {limit:.3g} {unit})"
    return None


def camera_matrix_problem(k: FloatArray, width_px: int, height_px: int) -> str | None:
    """What makes ``k`` no camera matrix for ``width_px`` x ``height_px`` images, or None when it is one.

    A pinhole K is ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with positive focal lengths of similar size, a small
    skew and the principal point near the image (OpenCV's calibrations never put it outside).
    """
    if k.shape != (3, 3):
        return f"camera matrix must be 3x3, got shape {k.shape}"
    if not np.all(np.isfinite(k)):
        return "camera matrix has non-finite entries"
    if k[1, 0] != 0.0 or not np.array_equal(k[2], [0.0, 0.0, 1.0]):
        return "camera matrix must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]"
    fx, fy, skew, cx, cy = k[0, 0], k[1, 1], k[0, 1], k[0, 2], k[1, 2]
    if fx <= 0.0 or fy <= 0.0:
        return f"focal lengths must be positive, got fx {fx:g}, fy {fy:g}"
    if not 0.2 <= fx / fy <= 5.0 or abs(skew) > 0.1 * fx:
        return f"not a camera's matrix: fx {fx:g}, fy {fy:g}, skew {skew:g} px"
    if not (-0.5 * width_px <= cx <= 1.5 * width_px and -0.5 * height_px <= cy <= 1.5 * height_px):
        return f"principal point ({cx:g}, {cy:g}) px lies far outside the {width_px}x{height_px} image"
    return None


@dataclass(frozen=True)
class PinholeCamera:
    """An intrinsically and extrinsically calibrated camera.

    ``camera_matrix``: (3, 3) float64 intrinsics K in pixels.
    ``dist_coeffs``: (5,) float64 OpenCV distortion ``k1, k2, p1, p2, k3``.
    ``rvec``, ``tvec``: (3,) float64 world-to-camera rotation (Rodrigues) and translation (cm).
    """

    camera_matrix: FloatArray
    dist_coeffs: FloatArray
    rvec: FloatArray
    tvec: FloatArray
    width_px: int
    height_px: int
    rotation: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        k = np.asarray(self.camera_matrix, dtype=np.float64)
        problem = camera_matrix_problem(k, self.width_px, self.height_px)
        if problem is not None:
            raise CalibrationError(problem)
        d = np.zeros(5, dtype=np.float64)
        dist = np.asarray(self.dist_coeffs, dtype=np.float64).ravel()
        d[: min(5, dist.size)] = dist[:5]
        object.__setattr__(self, "camera_matrix", k)
        object.__setattr__(self, "dist_coeffs", d)
        rvec = np.asarray(self.rvec, dtype=np.float64).reshape(3)
        tvec = np.asarray(self.tvec, dtype=np.float64).reshape(3)
        problem = pose_problem(rvec, tvec)
        if problem is not None:
            raise CalibrationError(problem)
        if not np.all(np.isfinite(d)):
            raise CalibrationError("distortion must be finite numbers")
        object.__setattr__(self, "rvec", rvec)
        object.__setattr__(self, "tvec", tvec)
        object.__setattr__(self, "rotation", cv2.Rodrigues(self.rvec)[0])

    # -- construction -------------------------------------------------------------------------------------------
    @classmethod
    def look_at(
        cls,
        position_cm: tuple[float, float, float],
        target_cm: tuple[float, float, float],
        *,
        width_px: int = 1280,
        height_px: int = 720,
        hfov_deg: float = 70.0,
        dist_coeffs: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0),
        principal_offset_px: tuple[float, float] = (0.0, 0.0),
        roll_deg: float = 0.0,
    ) -> PinholeCamera:
        """A camera at ``position_cm`` whose optical axis passes through ``target_cm`` (world z is up)."""
        pos = np.asarray(position_cm, dtype=np.float64)
        forward = np.asarray(target_cm, dtype=np.float64) - pos
        norm = float(np.linalg.norm(forward))
        if norm == 0.0:
            raise CalibrationError("camera position and target coincide")
        forward /= norm
        up_world = np.array([0.0, 0.0, 1.0])
        right = np.cross(forward, up_world)
        if np.linalg.norm(right) < 1e-9:  # looking straight down: pick world +y as image up
            right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rot = np.stack([right, down, forward])  # rows: camera axes in world coordinates
        if roll_deg:
            c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
            rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ rot
        fx = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        k = np.array(
            [
                [fx, 0.0, (width_px - 1) / 2.0 + principal_offset_px[0]],
                [0.0, fx, (height_px - 1) / 2.0 + principal_offset_px[1]],
                [0.0, 0.0, 1.0],
            ]
        )
        rvec = np.asarray(cv2.Rodrigues(rot)[0], dtype=np.float64).ravel()
        tvec = -rot @ pos
        return cls(k, np.asarray(dist_coeffs, dtype=np.float64), rvec, tvec, width_px, height_px)

    # -- geometry -----------------------------------------------------------------------------------------------
    @property
    def position_cm(self) -> FloatArray:
        """(3,) camera centre in world cm."""
        return np.asarray(-self.rotation.T @ self.tvec)

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist_coeffs != 0.0))

    def world_to_camera(self, xyz_world_cm: FloatArray) -> FloatArray:
        """(N, 3) world cm -> (N, 3) camera-frame cm."""
        pts = np.asarray(xyz_world_cm, dtype=np.float64).reshape(-1, 3)
        return np.asarray(pts @ self.rotation.T + self.tvec)

    def project(self, xyz_world_cm: FloatArray) -> FloatArray:
        """(N, 3) world cm -> (N, 2) distorted pixel coordinates (pixel centres at integers)."""
        pts = np.asarray(xyz_world_cm, dtype=np.float64).reshape(-1, 3)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        uv, _ = cv2.projectPoints(pts, self.rvec, self.tvec, self.camera_matrix, self.dist_coeffs)
        return np.asarray(uv.reshape(-1, 2), dtype=np.float64)

    def undistort_px(self, uv_px: FloatArray) -> FloatArray:
        """(N, 2) distorted pixels -> (N, 2) ideal (distortion-free) pixels under the same intrinsics."""
        uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
        if not self.has_distortion or uv.shape[0] == 0:
            return uv.reshape(-1, 2).copy()
        out = cv2.undistortPoints(
            uv,
            self.camera_matrix,
            self.dist_coeffs,
            P=self.camera_matrix,
            criteria=UNDISTORT_CRITERIA,
        )
        return np.asarray(out.reshape(-1, 2), dtype=np.float64)

    def pixel_to_plane(self, uv_px: FloatArray, z_cm: float) -> FloatArray:
        """(N, 2) distorted pixels -> (N, 2) world ``x, y`` cm where their rays meet the plane ``z = z_cm``."""
        ideal = self.undistort_px(uv_px)
        ones = np.ones((ideal.shape[0], 1))
        rays_cam = np.hstack([ideal, ones]) @ np.linalg.inv(self.camera_matrix).T
        rays_world = rays_cam @ self.rotation  # R^T applied to each row
        centre = self.position_cm
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z_cm - centre[2]) / rays_world[:, 2]
        xyz = centre + rays_world * s[:, None]
        return np.asarray(xyz[:, :2])

    def plane_homography(self, z_cm: float) -> FloatArray:
        """(3, 3) homography from world ``(x, y, 1)`` on the plane ``z = z_cm`` to ideal pixels."""
        r = self.rotation
        h = self.camera_matrix @ np.column_stack([r[:, 0], r[:, 1], r[:, 2] * z_cm + self.tvec])
        return np.asarray(h / h[2, 2])

    def in_front(self, xyz_world_cm: FloatArray) -> NDArray[np.bool_]:
        """(N,) bool: the points lie in front of the camera."""
        return np.asarray(self.world_to_camera(xyz_world_cm)[:, 2] > 1e-6)


class CameraFile(BaseModel):
    """On-disk form of a :class:`PinholeCamera` (``camera.json`` of the simulator, fiducial calibration)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: Literal["edge-ips/camera"] = "edge-ips/camera"
    version: Literal[1] = 1
    width_px: ImageSide
    height_px: ImageSide
    camera_matrix: Matrix3x3
    dist_coeffs: Distortion
    rvec: Vector3
    tvec: Vector3

    @classmethod
    def from_camera(cls, cam: PinholeCamera) -> CameraFile:
        return cls(
            width_px=cam.width_px,
            height_px=cam.height_px,
            camera_matrix=cam.camera_matrix.tolist(),
            dist_coeffs=cam.dist_coeffs.tolist(),
            rvec=cam.rvec.tolist(),
            tvec=cam.tvec.tolist(),
        )

    def to_camera(self) -> PinholeCamera:
        return PinholeCamera(
            np.asarray(self.camera_matrix, dtype=np.float64),
            np.asarray(self.dist_coeffs, dtype=np.float64),
            np.asarray(self.rvec, dtype=np.float64),
            np.asarray(self.tvec, dtype=np.float64),
            self.width_px,
            self.height_px,
        )


def save_camera(cam: PinholeCamera, path: Path) -> None:
    path.write_text(CameraFile.from_camera(cam).model_dump_json(indent=2) + "\n")


def load_camera(path: Path) -> PinholeCamera:
    try:
        return CameraFile.model_validate_json(path.read_bytes()).to_camera()
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read camera file ({exc.strerror})") from exc
    except ValidationError as exc:
        raise CalibrationError(f"{path}: invalid camera file at {describe_validation(exc)}") from exc
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: invalid camera file: {exc}") from None


# The paper's lab (section III.A): a Logitech C920 at 1280x720 (horizontal field of view about 70 degrees),
# 280 cm above the floor, beside the 391.5 x 549.5 cm working area, looking down obliquely along +y.
AREA_WIDTH_CM = 391.5
AREA_LENGTH_CM = 549.5
MARKER_HEIGHT_CM = 13.0
PAPER_CAMERA_HEIGHT_CM = 280.0
PAPER_CAMERA_SETBACK_CM = 200.0  # behind the near (y = 0) edge: the closest that keeps the whole area in view
PAPER_CAMERA_AIM_Y_CM = 200.0


def paper_camera(
    dist_coeffs: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0), principal_offset_px: tuple[float, float] = (0.0, 0.0)
) -> PinholeCamera:
    """The default camera: the paper's geometry, whole working area (floor and marker plane) in view; a real lens's
    distortion and principal point off the image centre when given."""
    return PinholeCamera.look_at(
        (AREA_WIDTH_CM / 2.0, -PAPER_CAMERA_SETBACK_CM, PAPER_CAMERA_HEIGHT_CM),
        (AREA_WIDTH_CM / 2.0, PAPER_CAMERA_AIM_Y_CM, 0.0),
        width_px=1280,
        height_px=720,
        hfov_deg=70.0,
        dist_coeffs=dist_coeffs,
        principal_offset_px=principal_offset_px,
    )
