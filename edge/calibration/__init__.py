"""Calibration: measured pixels to world cm on the marker plane (paper section III.A-B, made better).

The tracker needs only :class:`Calibration` (``pixel_to_world``, ``world_to_pixel``, ``image_size``,
``plane_height_cm``), :func:`load_calibration` and :func:`save_calibration`. The parts:

- ``points``: point-pair calibration with a leave-one-out outlier test and LOO accuracy figures.
- ``errormap``: the predicted 95% error of every pixel (paper Fig. 3/4) and its PNG.
- ``intrinsics``: lens intrinsics from checkerboard photos; ``lens``: undistorting points.
- ``fiducial``: the camera pose from ArUco markers at known floor positions, for any plane height.
- ``check``: a calibration against points surveyed but not used in its fit.
- ``exact``: the exact calibration of a known camera (the simulator's).
- ``workflow``: whole calibrations from the input files to the written file (the ``calibrate`` commands).
- ``survey``: where to put the survey points; ``files``: the runtime object and the versioned JSON file.
"""

from edge.calibration.check import CheckResult, check_calibration
from edge.calibration.files import (
    Calibration,
    CalibrationFile,
    load_calibration,
    read_calibration_file,
    save_calibration,
)
from edge.calibration.lens import Intrinsics
from edge.calibration.points import (
    PointsCalibration,
    PointTable,
    calibrate_points,
    fit_points,
    read_points_csv,
    write_points_csv,
)

__all__ = [
    "Calibration",
    "CalibrationFile",
    "CheckResult",
    "Intrinsics",
    "PointTable",
    "PointsCalibration",
    "calibrate_points",
    "check_calibration",
    "fit_points",
    "load_calibration",
    "read_calibration_file",
    "read_points_csv",
    "save_calibration",
    "write_points_csv",
]
