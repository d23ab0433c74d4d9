"""Fiducial calibration: one image of ArUco markers laid at known floor positions, no clicking.

Markers lie flat, printed upright with their top edge toward +y (the far side of the area); the markers CSV gives
each marker's ``id`` and centre ``x, y, z`` in cm, and its ``size`` (side of the black square, cm) as a column or
one size for all. Detection (``cv2.aruco.ArucoDetector``, sub-pixel corners) gives 4 image points per marker; the
camera pose follows from ``cv2.solvePnP`` (IPPE for coplanar markers, then Levenberg-Marquardt refinement). With
the pose known the camera maps onto any plane: a calibration made on the floor (z = 0) serves markers at 13 cm.

Without intrinsics the focal length is estimated from the same view (``cv2.calibrateCamera`` with the principal
point fixed at the image centre, square pixels and no distortion); the output says so, and a lens with visible
distortion should be calibrated with checkerboards first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration.files import Calibration
from edge.calibration.layout import MarkerCorners, layout_problem
from edge.calibration.lens import Intrinsics
from edge.calibration.pose import diagonal_crossing, fit_pose, solve_pose, square_corners
from edge.calibration.tables import NumericTable, parse_table, read_text
from edge.camera import MARKER_HEIGHT_CM, PinholeCamera
from edge.errors import CalibrationError

FloatArray = NDArray[np.float64]

DEFAULT_DICTIONARY = "DICT_4X4_50"
MIN_MARKERS_WITH_INTRINSICS = 2
MIN_MARKERS_WITHOUT_INTRINSICS = 3


@dataclass(frozen=True)
class MarkerTable:
    """``ids``: (M,) int; ``centres_cm``: (M, 3) x, y, z; ``sizes_cm``: (M,) black-square side."""

    source: str
    ids: NDArray[np.int64]
    centres_cm: FloatArray
    sizes_cm: FloatArray
    table: NumericTable

    def corners_cm(self, i: int) -> FloatArray:
        """(4, 3) world corners of marker ``i`` in ArUco order: top-left, top-right, bottom-right, bottom-left
        (top = +y side)."""
        return square_corners(self.centres_cm[i : i + 1], self.sizes_cm[i : i + 1])[0]


def read_markers_csv(path: Path, marker_size_cm: float | None = None) -> MarkerTable:
    return parse_markers_csv(read_text(path, "markers file"), str(path), marker_size_cm)


def parse_markers_csv(text: str, source: str, marker_size_cm: float | None = None) -> MarkerTable:
    """Parse ``id,x,y,z[,size]``; ``marker_size_cm`` applies where the table has no ``size`` column."""
    table = parse_table(text, source, ("id", "x", "y", "z"), ("size",))
    c = table.columns
    n = c["id"].size
    if n == 0:
        raise CalibrationError(f"{source}: no markers listed")
    if "size" in c:
        sizes = c["size"]
    elif marker_size_cm is not None:
        sizes = np.full(n, float(marker_size_cm))
    else:
        raise CalibrationError(f"{source}: no size column; give the marker size (side of the black square, cm)")
    seen: dict[int, int] = {}
    for i in range(n):
        raw_id = c["id"][i]
        if not 0 <= raw_id <= 999_999 or raw_id != int(raw_id):  # ArUco dictionaries hold at most 1024 ids
            raise CalibrationError(f"{table.where(i)}: id must be an integer 0-999999, got {raw_id:g}")
        if not sizes[i] > 0:
            raise CalibrationError(f"{table.where(i)}: marker size must be positive, got {sizes[i]:g}")
        if int(raw_id) in seen:
            raise CalibrationError(
                f"{table.where(i)}: duplicate marker id {int(raw_id)} (also row {seen[int(raw_id)]})"
            )
        seen[int(raw_id)] = int(table.rows[i])
    return MarkerTable(
        source=source,
        ids=c["id"].astype(np.int64),
        centres_cm=np.column_stack([c["x"], c["y"], c["z"]]),
        sizes_cm=np.asarray(sizes, dtype=np.float64),
        table=table,
    )


def detect_markers(image: NDArray[np.uint8], dictionary: str = DEFAULT_DICTIONARY) -> dict[int, FloatArray]:
    """id -> (4, 2) sub-pixel corners (top-left, top-right, bottom-right, bottom-left) of every marker found."""
    name = dictionary.upper()
    if not name.startswith("DICT_"):
        name = "DICT_" + name
    if not hasattr(cv2.aruco, name):
        raise CalibrationError(f"unknown ArUco dictionary {dictionary!r} (e.g. DICT_4X4_50, DICT_6X6_250)")
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 4
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 100
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)), params)
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _ = detector.detectMarkers(gray)
    found: dict[int, FloatArray] = {}
    if ids is None:
        return found
    for c, i in zip(corners, ids.ravel(), strict=True):
        found[int(i)] = np.asarray(c, dtype=np.float64).reshape(4, 2)
    return found


@dataclass(frozen=True)
class FiducialResult:
    """The camera recovered from one marker image, and how well it explains the markers.

    ``reprojection_rms_px``: RMS corner reprojection error. ``loo_error_cm``: per marker used, the distance between
    its surveyed centre and where a pose fitted without it puts it (on its own plane); None with too few markers.
    """

    camera: PinholeCamera
    calibration: Calibration
    ids_used: tuple[int, ...]
    ids_missing: tuple[int, ...]
    ids_unknown: tuple[int, ...]
    reprojection_rms_px: float
    loo_error_cm: FloatArray | None
    focal_estimated: bool
    notes: tuple[str, ...]


def calibrate_fiducial(
    image: NDArray[np.uint8],
    markers: MarkerTable,
    *,
    intrinsics: Intrinsics | None = None,
    height_cm: float = MARKER_HEIGHT_CM,
    dictionary: str = DEFAULT_DICTIONARY,
    area_cm: tuple[float, float, float, float] | None = None,
    source: str = "image",
) -> FiducialResult:
    """Recover the camera from one image of the markers and map it onto the plane ``z = height_cm``."""
    h, w = image.shape[:2]
    if not math.isfinite(height_cm):
        raise CalibrationError(f"plane height must be a finite number of cm, got {height_cm}")
    if intrinsics is not None and (intrinsics.width_px, intrinsics.height_px) != (w, h):
        raise CalibrationError(
            f"{source}: image is {w}x{h} but the intrinsics are for {intrinsics.width_px}x{intrinsics.height_px}"
        )
    found = detect_markers(image, dictionary)
    if not found:
        raise CalibrationError(f"{source}: no {dictionary} ArUco markers found in the image")
    known = {int(i): k for k, i in enumerate(markers.ids)}
    used = [i for i in sorted(found) if i in known]
    unknown = tuple(i for i in sorted(found) if i not in known)
    missing = tuple(int(i) for i in markers.ids if int(i) not in found)
    need = MIN_MARKERS_WITH_INTRINSICS if intrinsics is not None else MIN_MARKERS_WITHOUT_INTRINSICS
    if len(used) < need:
        raise CalibrationError(
            f"{source}: found {len(used)} of the markers listed in {markers.source} (ids {used or 'none'}), "
            f"need at least {need}; missing ids {list(missing)}"
        )
    obj = np.vstack([markers.corners_cm(known[i]) for i in used])
    img = np.vstack([found[i] for i in used])
    try:
        fit = fit_pose(obj, img, intrinsics, (w, h))
    except CalibrationError as exc:
        raise CalibrationError(f"{markers.source}: {exc}") from None
    rows = [known[i] for i in used]
    problem = layout_problem(
        MarkerCorners(
            ids=tuple(used),
            centres_cm=markers.centres_cm[rows],
            sizes_cm=markers.sizes_cm[rows],
            corners_px=np.stack([found[i] for i in used]),
            rows=tuple(markers.table.where(r) for r in rows),
        ),
        intrinsics,
        (w, h),
        markers.source,
    )
    if problem is not None:
        raise CalibrationError(f"{source}: {problem}")
    intrinsics = fit.intrinsics
    k, dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
    notes: list[str] = []
    if fit.focal_estimated:
        notes.append(
            f"no intrinsics given: focal length estimated from this view ({k[0, 0]:.1f} px, principal point at the "
            "image centre, no lens distortion)"
        )
    camera = PinholeCamera(k, dist, fit.rvec, fit.tvec, w, h)
    loo: FloatArray | None = None
    if len(used) >= need + 1:
        errs = []
        for mid in used:
            keep = np.array([m != mid for m in used for _ in range(4)])
            rv, tv = solve_pose(obj[keep], img[keep], k, dist)
            cam_j = PinholeCamera(k, dist, rv, tv, w, h)
            centre = markers.centres_cm[known[mid]]
            centre_px = intrinsics.distort_px(diagonal_crossing(intrinsics.undistort_px(found[mid]))[None])
            seen = cam_j.pixel_to_plane(centre_px, float(centre[2]))[0]
            errs.append(float(np.linalg.norm(seen - centre[:2])))
        loo = np.asarray(errs)
    if area_cm is None:
        lo = markers.centres_cm[:, :2].min(axis=0)
        hi = markers.centres_cm[:, :2].max(axis=0)
        area_cm = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    cal = Calibration(camera.plane_homography(height_cm), w, h, float(height_cm), area_cm, intrinsics, camera)
    return FiducialResult(
        camera=camera,
        calibration=cal,
        ids_used=tuple(used),
        ids_missing=missing,
        ids_unknown=unknown,
        reprojection_rms_px=fit.rms_px,
        loo_error_cm=loo,
        focal_estimated=fit.focal_estimated,
        notes=tuple(notes),
    )
