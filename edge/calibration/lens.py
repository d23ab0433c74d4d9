"""Camera intrinsics (K and lens distortion) as a value: undistort and distort points, never whole frames.

The paper corrects every frame (Table IV: 91.2 ms per frame); we map only the few points the tracker measures.
Pixel centres are at integer coordinates (OpenCV convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import UNDISTORT_CRITERIA, camera_matrix_problem
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]

# A lens model must map the image one to one and be invertible by cv2.undistortPoints: distorting what was
# undistorted gives the pixel back to well under the corner detector's noise. A model that folds over, or nearly
# so, inside the image (coefficients from a bad fit or a corrupted file) does not, and would map pixels to the
# wrong floor points.
ROUND_TRIP_TOLERANCE_PX = 0.05


@dataclass(frozen=True)
class Intrinsics:
    """``camera_matrix``: (3, 3) K in pixels; ``dist_coeffs``: (5,) OpenCV ``k1, k2, p1, p2, k3``."""

    camera_matrix: FloatArray
    dist_coeffs: FloatArray
    width_px: int
    height_px: int

    def __post_init__(self) -> None:
        k = np.asarray(self.camera_matrix, dtype=np.float64)
        problem = camera_matrix_problem(k, self.width_px, self.height_px)
        if problem is not None:
            raise CalibrationError(problem)
        object.__setattr__(self, "camera_matrix", k)
        d = np.zeros(5)
        given = np.asarray(self.dist_coeffs, dtype=np.float64).ravel()
        if given.size > 5 or not np.all(np.isfinite(given)):
            raise CalibrationError("distortion must be at most 5 finite numbers (k1, k2, p1, p2, k3)")
        d[: given.size] = given
        object.__setattr__(self, "dist_coeffs", d)
        if self.has_distortion:
            error_px = self._round_trip_error_px()
            if not error_px <= ROUND_TRIP_TOLERANCE_PX:  # also NaN
                raise CalibrationError(
                    f"the lens model (k1, k2, p1, p2, k3 = {', '.join(f'{c:.4g}' for c in d)}) cannot be inverted "
                    f"over the {self.width_px}x{self.height_px} image (a pixel comes back {error_px:.3g} px off): "
                    "not a lens this camera can have; calibrate the intrinsics again"
                )

    def _round_trip_error_px(self) -> float:
        """Largest ``|distort(undistort(p)) - p|`` over a grid of the image, its corners and edges included."""
        us = np.linspace(0.0, self.width_px - 1.0, 17)
        vs = np.linspace(0.0, self.height_px - 1.0, 11)
        grid = np.stack(np.meshgrid(us, vs), axis=-1).reshape(-1, 2)
        with np.errstate(all="ignore"):
            back = self.distort_px(self.undistort_px(grid))
            error = np.max(np.linalg.norm(back - grid, axis=1))
        return float(error) if np.isfinite(error) else float("inf")

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist_coeffs != 0.0))

    def undistort_px(self, uv_px: FloatArray) -> FloatArray:
        """(N, 2) measured (distorted) pixels -> (N, 2) ideal pixels under the same K."""
        uv = np.ascontiguousarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
        if not self.has_distortion or uv.shape[0] == 0:
            return uv.reshape(-1, 2).copy()
        k = self.camera_matrix
        out = cv2.undistortPoints(uv, k, self.dist_coeffs, P=k, criteria=UNDISTORT_CRITERIA)
        return np.asarray(out.reshape(-1, 2), dtype=np.float64)

    def distort_px(self, ideal_px: FloatArray) -> FloatArray:
        """(N, 2) ideal pixels -> (N, 2) pixels as the lens shows them."""
        ideal = np.asarray(ideal_px, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion or ideal.shape[0] == 0:
            return ideal.copy()
        k = self.camera_matrix
        rays = np.column_stack([(ideal - k[:2, 2]) @ np.linalg.inv(k[:2, :2]).T, np.ones(ideal.shape[0])])
        zero = np.zeros(3)
        uv, _ = cv2.projectPoints(rays, zero, zero, k, self.dist_coeffs)
        return np.asarray(uv.reshape(-1, 2), dtype=np.float64)
