"""Whole calibrations from their input files to the written calibration file: what the ``edge-ips calibrate``
commands run (they parse the options, call one of these and print the result)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from edge.calibration.check import CheckResult, check_calibration
from edge.calibration.errormap import write_error_map_png
from edge.calibration.fiducial import FiducialResult, MarkerTable, calibrate_fiducial, read_markers_csv
from edge.calibration.files import FitRecord, calibration_record, load_calibration, save_calibration
from edge.calibration.intrinsics import (
    IntrinsicsResult,
    calibrate_intrinsics,
    intrinsics_record,
    load_intrinsics,
    read_image,
    save_intrinsics,
)
from edge.calibration.lens import Intrinsics
from edge.calibration.points import PointsCalibration, PointTable, calibrate_points, read_points_csv
from edge.calibration.refine import Refined, refine_clicks
from edge.camera import MARKER_HEIGHT_CM
from edge.errors import CalibrationError

DEFAULT_IMAGE_SIZE = (1280, 720)  # the points' image size when no image, intrinsics or --size says it

AreaCm = tuple[float, float, float, float]


def points_image_size(
    background: NDArray[np.uint8] | None,
    intrinsics: Intrinsics | None,
    size: tuple[int, int] | None,
    *,
    image_path: Path | None = None,
    intrinsics_path: Path | None = None,
) -> tuple[int, int]:
    """The image size the points were measured in: the reference image's, else the intrinsics', else ``size``
    (``--size``), else 1280x720; the ones given must agree."""
    lens_size = None if intrinsics is None else (intrinsics.width_px, intrinsics.height_px)
    if background is not None and lens_size is not None and lens_size != background.shape[1::-1]:
        raise CalibrationError(
            f"{image_path} is {background.shape[1]}x{background.shape[0]} but {intrinsics_path} is for "
            f"{lens_size[0]}x{lens_size[1]} images"
        )
    if background is not None:
        found = (int(background.shape[1]), int(background.shape[0]))
    elif lens_size is not None:
        found = lens_size
    else:
        found = size or DEFAULT_IMAGE_SIZE
    if size is not None and size != found:
        raise CalibrationError(f"--size {size[0]}x{size[1]} does not match the {found[0]}x{found[1]} image/intrinsics")
    return found


@dataclass(frozen=True)
class PointsRun:
    """A point-pair calibration made from files: the points read, the image size used, the result."""

    table: PointTable
    image_size: tuple[int, int]
    result: PointsCalibration
    refined: Refined | None = None  # the clicks moved onto printed targets (``refine_on``; ``table`` has the moved)


def refine_points(table: PointTable, photo_path: Path, image_size: tuple[int, int]) -> tuple[PointTable, Refined]:
    """``table``'s clicks moved onto the X-corners of the printed targets in the photo ``photo_path``
    (``edge.calibration.refine``); a :class:`CalibrationError` where the photo is not of the points' size or no
    click has a target under it."""
    photo = read_image(photo_path)
    if photo.shape[1::-1] != image_size:
        raise CalibrationError(
            f"{photo_path} is {photo.shape[1]}x{photo.shape[0]} but the points are for {image_size[0]}x{image_size[1]} "
            "images: refine on a photo from the camera the points were clicked in"
        )
    refined = refine_clicks(photo, table.uv_px)
    if not refined.found.any():
        raise CalibrationError(
            f"{photo_path}: no printed target's corner near any of the {len(table)} clicks: is this the photo with "
            'the targets in place? (docs/calibration.md, "Printed targets on the points")'
        )
    return replace(table, uv_px=refined.uv_px), refined


def calibrate_points_files(
    points_csv: Path,
    out: Path,
    *,
    image: Path | None = None,
    error_map: Path | None = None,
    height_cm: float = MARKER_HEIGHT_CM,
    intrinsics: Path | None = None,
    size: tuple[int, int] | None = None,
    area_cm: AreaCm | None = None,
    detect_outliers: bool = True,
    refine_on: Path | None = None,
) -> PointsRun:
    """Fit the points of ``points_csv`` (the outlier test on), write the error map PNG (when asked and there is
    one: it needs 5 points) and the calibration file ``out``; ``refine_on``: a photo of printed targets on the
    points, the clicks moved onto them first (:func:`refine_points`)."""
    background = read_image(image) if image is not None else None
    lens = load_intrinsics(intrinsics) if intrinsics is not None else None
    image_size = points_image_size(background, lens, size, image_path=image, intrinsics_path=intrinsics)
    table = read_points_csv(points_csv)
    refined = None
    if refine_on is not None:
        table, refined = refine_points(table, refine_on, image_size)
    result = calibrate_points(
        table,
        image_size,
        height_cm=height_cm,
        intrinsics=lens,
        area_cm=area_cm,
        detect_outliers=detect_outliers,
    )
    if result.error_map is not None and error_map is not None:
        used = result.fit.used
        write_error_map_png(
            error_map,
            result.error_map,
            result.calibration,
            points_uv_px=table.uv_px[used],
            rejected_uv_px=table.uv_px[~used],
            background=background,
        )
    save_calibration(result.record, out)
    return PointsRun(table, image_size, result, refined)


def calibrate_intrinsics_files(
    images: Iterable[Path], board: tuple[int, int], square_cm: float, out: Path, *, allow_missing: bool = False
) -> IntrinsicsResult:
    """Lens intrinsics from checkerboard photos (read one by one, as they are searched), written to ``out``."""
    photos = ((str(path), read_image(path)) for path in images)
    result = calibrate_intrinsics(photos, board, square_cm, allow_missing=allow_missing)
    save_intrinsics(intrinsics_record(result), out)
    return result


@dataclass(frozen=True)
class ArucoRun:
    """An ArUco calibration made from files: the marker table read and the result."""

    table: MarkerTable
    result: FiducialResult


def calibrate_aruco_files(
    image: Path,
    markers: Path,
    out: Path,
    *,
    marker_size_cm: float | None = None,
    intrinsics: Path | None = None,
    height_cm: float = MARKER_HEIGHT_CM,
    dictionary: str = "DICT_4X4_50",
    area_cm: AreaCm | None = None,
) -> ArucoRun:
    """The camera's pose from one image of ArUco markers at known places, mapped onto ``z = height_cm``, with
    its figures (corner reprojection, leave-one-marker-out errors) written to ``out``."""
    photo = read_image(image)
    table = read_markers_csv(markers, marker_size_cm)
    lens = load_intrinsics(intrinsics) if intrinsics is not None else None
    result = calibrate_fiducial(
        photo,
        table,
        intrinsics=lens,
        height_cm=height_cm,
        dictionary=dictionary,
        area_cm=area_cm,
        source=str(image),
    )
    loo = result.loo_error_cm
    stats = FitRecord(
        n_points=len(table.ids),
        n_used=len(result.ids_used),
        reprojection_rms_px=result.reprojection_rms_px,
        loo_mean_cm=None if loo is None else float(loo.mean()),
        loo_max_cm=None if loo is None else float(loo.max()),
        loo_rms_cm=None if loo is None else float((loo**2).mean() ** 0.5),
        notes=list(result.notes),
    )
    save_calibration(calibration_record(result.calibration, method="aruco", source=str(image), fit=stats), out)
    return ArucoRun(table, result)


def check_calibration_files(calibration_json: Path, check_csv: Path) -> CheckResult:
    """A calibration file against a CSV of points surveyed but not used in its fit."""
    return check_calibration(load_calibration(calibration_json), read_points_csv(check_csv))
