"""The runtime Calibration and its versioned JSON file: round trip, mapping, and every way a file can be wrong."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.calibration import Calibration, Intrinsics, load_calibration, save_calibration
from edge.calibration.files import calibration_record, read_calibration_file
from edge.calibration.points import calibrate_points, point_table
from edge.camera import paper_camera
from edge.errors import CalibrationError
from edge.sim.targets import PAPER_AREA, survey_points
from tests.support.calibration import DISTORTION


def _points_calibration_file(tmp_path: Path) -> Path:
    s = survey_points(paper_camera(), rng=0)
    result = calibrate_points(point_table(s.uv_px, s.xy_world_cm, "survey.csv"), (1280, 720), area_cm=PAPER_AREA)
    path = tmp_path / "calibration.json"
    save_calibration(result.record, path)
    return path


def test_calibration_file_round_trips_with_its_statistics(tmp_path: Path) -> None:
    path = _points_calibration_file(tmp_path)
    record = read_calibration_file(path)
    assert record.kind == "edge-ips/calibration" and record.version == 1 and record.method == "points"
    assert (record.image_width_px, record.image_height_px, record.plane_height_cm) == (1280, 720, 13.0)
    assert record.fit is not None and record.fit.n_points == 34 and record.fit.loo_mean_cm is not None
    assert len(record.points) == 34 and record.points[0].row == 1
    cal = load_calibration(path, expected_size=(1280, 720))
    assert cal.image_size == (1280, 720) and cal.plane_height_cm == 13.0
    uv = np.array([[640.0, 360.0], [100.0, 650.0]])
    again = load_calibration(path)
    np.testing.assert_allclose(cal.pixel_to_world(uv), again.pixel_to_world(uv))


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(0.0, 391.5),
    y=st.floats(0.0, 549.5),
    distorted=st.booleans(),
)
def test_world_to_pixel_inverts_pixel_to_world(x: float, y: float, distorted: bool) -> None:
    camera = paper_camera(DISTORTION if distorted else (0.0,) * 5)
    intr = Intrinsics(camera.camera_matrix, camera.dist_coeffs, 1280, 720) if distorted else None
    cal = Calibration(camera.plane_homography(13.0), 1280, 720, 13.0, PAPER_AREA, intr)
    uv = cal.world_to_pixel(np.array([[x, y]]))
    np.testing.assert_allclose(uv, camera.project(np.array([[x, y, 13.0]])), atol=1e-6)
    np.testing.assert_allclose(cal.pixel_to_world(uv), [[x, y]], atol=1e-6)


def test_pixel_to_world_is_vectorised_and_marks_pixels_that_miss_the_plane() -> None:
    camera = paper_camera()
    cal = Calibration(camera.plane_homography(13.0), 1280, 720, 13.0, PAPER_AREA)
    assert cal.pixel_to_world(np.zeros((0, 2))).shape == (0, 2)
    many = np.random.default_rng(0).uniform([0, 100], [1279, 719], (1000, 2))
    out = cal.pixel_to_world(many)
    assert out.shape == (1000, 2) and np.all(np.isfinite(out))
    # a camera tilted up sees the horizon: pixels above it have no floor point
    high = Calibration(camera.plane_homography(13.0), 1280, 720, 13.0, PAPER_AREA)
    horizon_v = high.homography_world_to_px @ np.array([0.0, 1.0, 0.0])  # vanishing point of the +y direction
    above = np.array([[horizon_v[0] / horizon_v[2], horizon_v[1] / horizon_v[2] - 50.0]])
    assert np.all(np.isnan(high.pixel_to_world(above)))


def test_only_a_calibration_with_a_camera_pose_changes_height() -> None:
    camera = paper_camera()
    with_pose = Calibration(
        camera.plane_homography(0.0),
        1280,
        720,
        0.0,
        PAPER_AREA,
        Intrinsics(camera.camera_matrix, camera.dist_coeffs, 1280, 720),
        camera,
    )
    raised = with_pose.at_height(13.0)
    uv = camera.project(np.array([[100.0, 200.0, 13.0]]))
    np.testing.assert_allclose(raised.pixel_to_world(uv), [[100.0, 200.0]], atol=1e-6)
    no_pose = Calibration(camera.plane_homography(13.0), 1280, 720, 13.0, PAPER_AREA)
    with pytest.raises(CalibrationError, match="no camera pose"):
        no_pose.at_height(0.0)


def test_a_camera_calibration_survives_the_file(tmp_path: Path) -> None:
    camera = paper_camera(DISTORTION)
    intr = Intrinsics(camera.camera_matrix, camera.dist_coeffs, 1280, 720)
    cal = Calibration(camera.plane_homography(0.0), 1280, 720, 0.0, PAPER_AREA, intr, camera)
    path = tmp_path / "cal.json"
    save_calibration(cal, path)
    back = load_calibration(path).at_height(13.0)
    uv = camera.project(np.array([[300.0, 500.0, 13.0]]))
    np.testing.assert_allclose(back.pixel_to_world(uv), [[300.0, 500.0]], atol=1e-6)


def _edit(path: Path, **changes: object) -> Path:
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))
    return path


@pytest.mark.slow
@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"version": 2}, "unknown calibration file version 2"),
        ({"version": None}, "unknown calibration file version None"),
        ({"kind": "edge-ips/camera"}, "not an edge-ips calibration file"),
        ({"homography_world_to_px": [[1, 2, 3], [2, 4, 6], [0, 0, 1]]}, "degenerate mapping"),
        ({"homography_world_to_px": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]}, "degenerate mapping"),
        ({"image_width_px": -5}, "invalid calibration file at image_width_px"),
        ({"plane_height_cm": "high"}, "invalid calibration file at plane_height_cm"),
        ({"surprise": 1}, "invalid calibration file at surprise"),
    ],
)
def test_bad_calibration_files_say_what_is_wrong(tmp_path: Path, change: dict, message: str) -> None:  # type: ignore[type-arg]
    path = _edit(_points_calibration_file(tmp_path), **change)
    with pytest.raises(CalibrationError, match=message) as info:
        load_calibration(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"{not json", "malformed JSON at line 1"),
        (b"[1, 2]", "expected a JSON object"),
        (b"\xff\xfe\x00", "not UTF-8"),
    ],
)
def test_unreadable_calibration_files_say_what_is_wrong(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "calibration.json"
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


def test_missing_calibration_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match=r"nope\.json: cannot read calibration file"):
        load_calibration(tmp_path / "nope.json")


def test_a_file_for_another_image_size_is_refused(tmp_path: Path) -> None:
    path = _points_calibration_file(tmp_path)
    with pytest.raises(CalibrationError, match="for 1280x720 images but the camera delivers 640x480"):
        load_calibration(path, expected_size=(640, 480))


def test_record_of_a_bare_calibration_has_no_statistics() -> None:
    camera = paper_camera()
    record = calibration_record(
        Calibration(camera.plane_homography(13.0), 1280, 720, 13.0, PAPER_AREA), method="points"
    )
    assert record.fit is None and record.points == [] and record.rejected == []
