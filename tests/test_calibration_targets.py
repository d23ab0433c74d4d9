"""edge.sim.targets: synthetic calibration inputs with exact ground truth, as a person would make them."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from edge.calibration.points import read_points_csv
from edge.camera import paper_camera
from edge.sim.targets import (
    aruco_floor_frame,
    check_points,
    checkerboard_views,
    survey_layout,
    survey_points,
    write_markers_csv,
)


def test_survey_points_are_on_the_grid_at_marker_height_with_the_stated_noise() -> None:
    camera = paper_camera()
    radial = []
    for seed in range(40):
        s = survey_points(camera, n=34, grid_cm=30.0, height_cm=13.0, noise_px=0.5, rng=seed)
        np.testing.assert_array_equal(s.xy_world_cm, survey_layout(camera))
        np.testing.assert_allclose(
            s.uv_true_px, camera.project(np.column_stack([s.xy_world_cm, np.full(34, 13.0)])), atol=1e-9
        )
        radial.append(np.linalg.norm(s.uv_px - s.uv_true_px, axis=1))
    rms = math.sqrt(float(np.mean(np.concatenate(radial) ** 2)))
    assert rms == pytest.approx(0.5, rel=0.05)  # 0.5 px RMS radial


def test_same_seed_same_survey_and_csv_round_trip(tmp_path: Path) -> None:
    camera = paper_camera()
    a, b = survey_points(camera, rng=3), survey_points(camera, rng=3)
    np.testing.assert_array_equal(a.uv_px, b.uv_px)
    a.write_csv(tmp_path / "p.csv")
    table = read_points_csv(tmp_path / "p.csv")
    np.testing.assert_allclose(table.uv_px, a.uv_px, atol=6e-4)


def test_check_points_are_inside_the_area_and_off_the_grid() -> None:
    s = check_points(paper_camera(), n=50, rng=1)
    assert np.all((s.xy_world_cm >= 0) & (s.xy_world_cm <= [391.5, 549.5]))
    assert not np.any(np.all(np.mod(s.xy_world_cm, 30.0) == 0.0, axis=1))


@pytest.mark.slow
def test_checkerboard_views_cover_the_image_and_stay_inside_it() -> None:
    views = checkerboard_views(paper_camera(), n_views=12, rng=0)
    assert len(views.images) == 12 and views.images[0].shape == (720, 1280, 3)
    dark = [np.argwhere(cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) < 60) for im in views.images]
    centres = np.array([d.mean(axis=0) for d in dark])  # (row, col) of the black squares
    assert centres[:, 1].min() < 400 and centres[:, 1].max() > 880  # left and right thirds
    assert centres[:, 0].min() < 250 and centres[:, 0].max() > 470  # top and bottom thirds


def test_aruco_frame_draws_markers_where_the_table_says(tmp_path: Path) -> None:
    camera = paper_camera()
    frame = aruco_floor_frame(camera, rng=0)
    gray = cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY)
    for marker in frame.markers:
        u, v = camera.project(marker[None, 1:4])[0]
        # the marker's black border ring: dark just inside the outline; white quiet zone just outside
        x, y, z, size = marker[1], marker[2], marker[3], marker[4]
        inside = camera.project(np.array([[x - 0.45 * size, y, z]]))[0]
        outside = camera.project(np.array([[x - 0.6 * size, y, z]]))[0]
        assert gray[round(inside[1]), round(inside[0])] < 80
        assert gray[round(outside[1]), round(outside[0])] > 180
        assert 0 <= u < 1280 and 0 <= v < 720
    write_markers_csv(tmp_path / "m.csv", frame.markers)
    assert (tmp_path / "m.csv").read_text().splitlines()[0] == "id,x,y,z,size"
