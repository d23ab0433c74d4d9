"""The exact calibration of a known camera (the simulator's): no measurement, the camera model itself."""

from __future__ import annotations

from edge.calibration.files import Calibration
from edge.calibration.lens import Intrinsics
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM, PinholeCamera


def exact_calibration(camera: PinholeCamera, z_cm: float | None = None) -> Calibration:
    """The exact :class:`edge.calibration.Calibration` of a known camera on the plane at ``z_cm`` (default: the
    marker plane)."""
    z = MARKER_HEIGHT_CM if z_cm is None else z_cm
    lens = Intrinsics(camera.camera_matrix, camera.dist_coeffs, camera.width_px, camera.height_px)
    return Calibration(
        camera.plane_homography(z),
        camera.width_px,
        camera.height_px,
        z,
        (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM),
        lens,
        camera,
    )
