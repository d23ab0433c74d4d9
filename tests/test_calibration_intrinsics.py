"""Intrinsics from rendered checkerboard photos, and ArUco fiducial calibration from one rendered floor frame."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from edge.calibration.fiducial import calibrate_fiducial, detect_markers, parse_markers_csv
from edge.calibration.intrinsics import (
    board_object_points,
    calibrate_intrinsics,
    find_board,
    intrinsics_record,
    load_intrinsics,
    parse_board,
    save_intrinsics,
)
from edge.calibration.lens import Intrinsics
from edge.camera import PinholeCamera, paper_camera
from edge.errors import CalibrationError
from edge.sim.targets import CheckerboardViews, aruco_floor_frame, checkerboard_views
from tests.support.calibration import DISTORTION, true_errors_cm


@pytest.fixture(scope="module")
def lens_camera() -> PinholeCamera:
    return paper_camera(DISTORTION)


@pytest.fixture(scope="module")
def boards(lens_camera: PinholeCamera) -> CheckerboardViews:
    return checkerboard_views(lens_camera, rng=5)


@pytest.mark.slow
def test_rendered_checkerboard_corners_are_found_where_the_geometry_puts_them(
    lens_camera: PinholeCamera, boards: CheckerboardViews
) -> None:
    obj = board_object_points(boards.board, boards.square_cm)
    for image, (rvec, tvec) in zip(boards.images, boards.board_poses, strict=True):
        corners = find_board(image, boards.board)
        assert corners is not None
        truth, _ = cv2.projectPoints(obj, rvec, tvec, lens_camera.camera_matrix, lens_camera.dist_coeffs)
        truth = truth.reshape(-1, 2)
        err = min(np.abs(corners - truth).max(), np.abs(corners[::-1] - truth).max())  # the board is symmetric
        assert err < 0.15


@pytest.mark.slow
def test_intrinsics_from_checkerboards_recover_the_lens(lens_camera: PinholeCamera, boards: CheckerboardViews) -> None:
    result = calibrate_intrinsics([(f"b{i}.png", im) for i, im in enumerate(boards.images)], (9, 6), 2.5)
    assert result.rms_px < 0.1
    k, k_true = result.intrinsics.camera_matrix, lens_camera.camera_matrix
    assert k[0, 0] == pytest.approx(k_true[0, 0], rel=0.003)
    assert k[:2, 2] == pytest.approx(k_true[:2, 2], abs=2.0)
    # what matters: undistorted points agree with the true lens over the whole image (to a homography: K errors
    # are absorbed by the plane fit), here checked directly against the truth at the image corners
    uv = np.array([[5.0, 5.0], [1274.0, 5.0], [5.0, 714.0], [1274.0, 714.0], [640.0, 360.0]])
    truth = Intrinsics(k_true, lens_camera.dist_coeffs, 1280, 720).undistort_px(uv)
    assert np.max(np.abs(result.intrinsics.undistort_px(uv) - truth)) < 1.5


@pytest.mark.slow
def test_intrinsics_file_round_trip_and_size_check(tmp_path: Path, boards: CheckerboardViews) -> None:
    result = calibrate_intrinsics([(f"b{i}.png", im) for i, im in enumerate(boards.images)], (9, 6), 2.5)
    path = tmp_path / "intrinsics.json"
    save_intrinsics(intrinsics_record(result), path)
    back = load_intrinsics(path, expected_size=(1280, 720))
    np.testing.assert_allclose(back.camera_matrix, result.intrinsics.camera_matrix)
    with pytest.raises(CalibrationError, match="intrinsics are for 1280x720 images, not 640x480"):
        load_intrinsics(path, expected_size=(640, 480))


@pytest.mark.slow
def test_a_photo_without_the_board_is_named_or_skipped(boards: CheckerboardViews) -> None:
    blank = np.full((720, 1280, 3), 128, np.uint8)
    photos = [(f"b{i}.png", im) for i, im in enumerate(boards.images)] + [("empty.png", blank)]
    with pytest.raises(CalibrationError, match=r"empty.png: no 9x6 checkerboard found"):
        calibrate_intrinsics(photos, (9, 6), 2.5)
    result = calibrate_intrinsics(photos, (9, 6), 2.5, allow_missing=True)
    assert result.skipped == (("empty.png", "no 9x6 checkerboard found"),)
    assert "empty.png" not in result.used


@pytest.mark.slow
def test_too_few_views_and_mixed_sizes_are_refused(boards: CheckerboardViews) -> None:
    photos = [(f"b{i}.png", im) for i, im in enumerate(boards.images[:3])]
    with pytest.raises(CalibrationError, match="board found in 3 image"):
        calibrate_intrinsics(photos, (9, 6), 2.5)
    small = cv2.resize(boards.images[0], (640, 360))
    with pytest.raises(CalibrationError, match=r"small\.png: image is 640x360 but the first image is 1280x720"):
        calibrate_intrinsics([photos[0], ("small.png", small)], (9, 6), 2.5)


@pytest.mark.parametrize(("text", "expected"), [("9x6", (9, 6)), ("7X5", (7, 5)), (" 4 x 3 ", (4, 3))])
def test_board_sizes_parse(text: str, expected: tuple[int, int]) -> None:
    assert parse_board(text) == expected


@pytest.mark.parametrize("text", ["9", "9x", "axb", "1x6", "9x6x2"])
def test_bad_board_sizes_are_refused(text: str) -> None:
    with pytest.raises(CalibrationError, match="board"):
        parse_board(text)


# -- ArUco ---------------------------------------------------------------------------------------------------------
def _markers_table(frame_markers: np.ndarray) -> str:
    return "id,x,y,z,size\n" + "\n".join(",".join(f"{v:g}" for v in m) for m in frame_markers)


def test_markers_are_detected_with_ids_and_sub_pixel_corners() -> None:
    camera = paper_camera()
    frame = aruco_floor_frame(camera, rng=0)
    markers = parse_markers_csv(_markers_table(frame.markers), "markers.csv")
    found = detect_markers(frame.image)
    assert sorted(found) == list(range(12))
    for k, marker_id in enumerate(markers.ids):
        truth = camera.project(markers.corners_cm(k))
        centre_truth = camera.project(markers.centres_cm[k][None])[0]
        assert np.linalg.norm(found[int(marker_id)].mean(axis=0) - centre_truth) < 1.0
        assert np.abs(found[int(marker_id)] - truth).max() < 2.0


@pytest.mark.slow
def test_floor_markers_calibrate_the_marker_plane_at_13_cm(
    lens_camera: PinholeCamera, boards: CheckerboardViews
) -> None:
    intr = calibrate_intrinsics([(f"b{i}", im) for i, im in enumerate(boards.images)], (9, 6), 2.5).intrinsics
    frame = aruco_floor_frame(lens_camera, rng=1)
    markers = parse_markers_csv(_markers_table(frame.markers), "markers.csv")
    result = calibrate_fiducial(frame.image, markers, intrinsics=intr, height_cm=13.0)
    assert result.calibration.plane_height_cm == 13.0 and not result.focal_estimated
    np.testing.assert_allclose(result.camera.position_cm, lens_camera.position_cm, atol=2.0)
    err = true_errors_cm(result.calibration, lens_camera, z_cm=13.0)
    assert err.mean() < 0.3 and err.max() < 1.0
    # the same calibration, moved back to the floor, maps floor points
    floor = result.calibration.at_height(0.0)
    assert true_errors_cm(floor, lens_camera, z_cm=0.0).max() < 1.0
    # ignoring the 13 cm would cost centimetres: the plane height matters
    assert true_errors_cm(floor, lens_camera, z_cm=13.0).mean() > 5.0
    assert result.loo_error_cm is not None and result.loo_error_cm.max() < 2.0


def test_without_intrinsics_the_focal_length_is_estimated_and_said() -> None:
    camera = paper_camera()
    frame = aruco_floor_frame(camera, rng=2)
    markers = parse_markers_csv(_markers_table(frame.markers), "markers.csv")
    result = calibrate_fiducial(frame.image, markers)
    assert result.focal_estimated
    assert any("focal length estimated" in n for n in result.notes)
    assert result.camera.camera_matrix[0, 0] == pytest.approx(camera.camera_matrix[0, 0], rel=0.01)
    assert true_errors_cm(result.calibration, camera).max() < 0.5


def test_markers_missing_from_the_image_or_the_table_are_reported() -> None:
    camera = paper_camera()
    positions = ((60.0, 60.0), (330.0, 60.0), (195.0, 250.0), (60.0, 420.0), (330.0, 420.0))
    frame = aruco_floor_frame(camera, positions_cm=positions, rng=3)
    rows = _markers_table(frame.markers[:4]) + "\n40,195,500,0,25"  # marker 4 not listed; 40 not in the image
    result = calibrate_fiducial(frame.image, parse_markers_csv(rows, "markers.csv"))
    assert result.ids_unknown == (4,) and result.ids_missing == (40,)
    assert result.ids_used == (0, 1, 2, 3)


@pytest.mark.parametrize(
    ("text", "size", "message"),
    [
        ("id,x,y\n0,1,2", None, "header must name the columns id,x,y,z"),
        ("id,x,y,z\n0,1,2,0", None, "no size column"),
        ("id,x,y,z,size\n0,1,2,0,25\n0,5,6,0,25", None, r"row 2 \(line 3\): duplicate marker id 0"),
        ("id,x,y,z,size\n1.5,1,2,0,25", None, "row 1 .*id must be an integer 0-999999"),
        ("id,x,y,z,size\n1e30,1,2,0,25", None, "row 1 .*id must be an integer 0-999999, got 1e\\+30"),
        ("id,x,y,z\n0,1,2,0", -3.0, "row 1 .*marker size must be positive"),
        ("id,x,y,z,size\n0,1,nan,0,25", None, "row 1 .*y is not a finite number"),
        ("id,x,y,z,size", None, "no markers listed"),
    ],
)
def test_bad_marker_tables_name_the_row(text: str, size: float | None, message: str) -> None:
    with pytest.raises(CalibrationError, match=message):
        parse_markers_csv(text, "markers.csv", size)


def test_an_image_without_markers_is_a_clear_error() -> None:
    markers = parse_markers_csv("id,x,y,z,size\n0,1,2,0,25\n1,100,2,0,25\n2,1,200,0,25", "markers.csv")
    with pytest.raises(CalibrationError, match=r"floor\.png: no DICT_4X4_50 ArUco markers found"):
        calibrate_fiducial(np.full((720, 1280, 3), 100, np.uint8), markers, source="floor.png")
