"""A camera pose from flat square markers at known places: the corners of each marker, the focal length when no
intrinsics are known, ``solvePnP`` and the corner reprojection error. Shared by the fiducial calibration and the
check that its marker table is the layout in the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.lens import Intrinsics
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]

# ArUco corner order (top-left, top-right, bottom-right, bottom-left) of a square with its top edge toward +y,
# as offsets from its centre in half sides.
_CORNER_OFFSETS = np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])


def square_corners(centres_cm: FloatArray, sizes_cm: FloatArray, quarter_turns: int = 0) -> FloatArray:
    """(M, 4, 3) world corners, in ArUco order, of flat squares with centres (M, 3) and sides (M,) cm whose top
    edge points toward +y turned counter-clockwise (seen from above) by ``quarter_turns`` x 90 degrees."""
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][quarter_turns % 4]
    turned = _CORNER_OFFSETS @ np.array([[c, s], [-s, c]])  # rows rotated by the angle: (x c - y s, x s + y c)
    centres = np.asarray(centres_cm, dtype=np.float64).reshape(-1, 3)
    half = np.asarray(sizes_cm, dtype=np.float64).reshape(-1, 1, 1) / 2.0
    corners = np.repeat(centres[:, None, :], 4, axis=1)
    corners[:, :, :2] += turned[None] * half
    return corners


def diagonal_crossing(corners_px: FloatArray) -> FloatArray:
    """(2,) where the diagonals of a quadrilateral (4, 2) cross: the image of a square's centre under perspective."""
    h = np.column_stack([corners_px, np.ones(4)])
    p = np.cross(np.cross(h[0], h[2]), np.cross(h[1], h[3]))
    return np.asarray(p[:2] / p[2])


def estimate_focal(obj: FloatArray, img: FloatArray, size: tuple[int, int]) -> FloatArray:
    """(3, 3) K from one planar view: principal point at the centre, square pixels, no distortion."""
    w, h = size
    k0 = np.array([[float(max(w, h)), 0.0, (w - 1) / 2.0], [0.0, float(max(w, h)), (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_FIX_PRINCIPAL_POINT
        | cv2.CALIB_FIX_ASPECT_RATIO
        | cv2.CALIB_ZERO_TANGENT_DIST
        | cv2.CALIB_FIX_K1
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
    )
    _, k, _, _, _ = cv2.calibrateCamera(
        [obj.astype(np.float32)], [img.astype(np.float32).reshape(-1, 1, 2)], size, k0, np.zeros(5), flags=flags
    )
    return np.asarray(k, dtype=np.float64)


def solve_pose(obj: FloatArray, img: FloatArray, k: FloatArray, dist: FloatArray) -> tuple[FloatArray, FloatArray]:
    """World -> camera (rvec, tvec) from point correspondences; IPPE when the points are coplanar in z."""
    z0 = float(obj[:, 2].mean())
    coplanar = bool(np.all(np.abs(obj[:, 2] - z0) < 1e-6))
    shifted = obj - np.array([0.0, 0.0, z0]) if coplanar else obj
    method = cv2.SOLVEPNP_IPPE if coplanar else cv2.SOLVEPNP_SQPNP
    ok, rvec, tvec = cv2.solvePnP(shifted, img, k, dist, flags=method)
    if not ok:
        raise CalibrationError("cannot recover the camera pose from the markers (degenerate layout?)")
    rvec, tvec = cv2.solvePnPRefineLM(shifted, img, k, dist, rvec, tvec)
    r = cv2.Rodrigues(rvec)[0]
    tvec = tvec.reshape(3) - r[:, 2] * z0 if coplanar else tvec.reshape(3)
    return np.asarray(rvec, dtype=np.float64).reshape(3), np.asarray(tvec, dtype=np.float64)


@dataclass(frozen=True)
class PoseFit:
    """A camera fitted to marker corners: ``rms_px`` is the corner reprojection RMS; ``focal_estimated`` when
    ``intrinsics`` came from the same view."""

    intrinsics: Intrinsics
    rvec: FloatArray
    tvec: FloatArray
    rms_px: float
    focal_estimated: bool


def fit_pose(obj: FloatArray, img: FloatArray, intrinsics: Intrinsics | None, size: tuple[int, int]) -> PoseFit:
    """The camera that sees the world points ``obj`` (N, 3) cm at the pixels ``img`` (N, 2); without intrinsics
    the focal length is estimated from the same (planar) view."""
    focal_estimated = intrinsics is None
    if intrinsics is None:
        if np.ptp(obj[:, 2]) > 1e-6:
            raise CalibrationError("markers at different heights need intrinsics (--intrinsics) to calibrate")
        k = estimate_focal(obj - np.array([0.0, 0.0, obj[:, 2].mean()]), img, size)
        intrinsics = Intrinsics(k, np.zeros(5), size[0], size[1])
    k, dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
    rvec, tvec = solve_pose(obj, img, k, dist)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    return PoseFit(intrinsics, rvec, tvec, rms, focal_estimated)
