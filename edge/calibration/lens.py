"""Camera intrinsics (K and lens distortion) as a value: undistort and distort points, never whole frames.

The paper corrects every frame (Table IV: 91.2 ms per frame); we map only the few points the tracker measures.
Pixel centres are at integer coordinates (OpenCV convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# cv2.undistortPoints' default (5 iterations) leaves ~0.003 px at the corners of a strongly distorted image;
# 20 iterations reach 1e-9 px for any lens a webcam has, at well under a microsecond per point.
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-9)


@dataclass(frozen=True)
class Intrinsics:
    """``camera_matrix``: (3, 3) K in pixels; ``dist_coeffs``: (5,) OpenCV ``k1, k2, p1, p2, k3``."""

    camera_matrix: FloatArray
    dist_coeffs: FloatArray
    width_px: int
    height_px: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "camera_matrix", np.asarray(self.camera_matrix, dtype=np.float64).reshape(3, 3))
        d = np.zeros(5)
        given = np.asarray(self.dist_coeffs, dtype=np.float64).ravel()[:5]
        d[: given.size] = given
        object.__setattr__(self, "dist_coeffs", d)

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
