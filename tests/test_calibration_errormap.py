"""The error map (paper Fig. 3/4): predicted 95% error per pixel, its honesty, and its PNG."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from edge.calibration.errormap import area_mask, predicted_error_map, radial_quantile, write_error_map_png
from edge.calibration.points import calibrate_points, point_table
from edge.camera import MARKER_HEIGHT_CM, paper_camera
from edge.sim.targets import PAPER_AREA, survey_points


@pytest.mark.slow
@pytest.mark.parametrize("ratio", [0.0, 0.05, 0.3, 0.7, 1.0])
@pytest.mark.parametrize("angle", [0.0, 0.7])
def test_radial_quantile_contains_95_percent_of_gaussian_errors(ratio: float, angle: float) -> None:
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    cov = rot @ np.diag([4.0, 4.0 * ratio]) @ rot.T
    r95 = float(radial_quantile(cov[None])[0])
    samples = np.random.default_rng(1).multivariate_normal([0.0, 0.0], cov, size=200_000)
    inside = np.mean(np.linalg.norm(samples, axis=1) <= r95)
    assert inside == pytest.approx(0.95, abs=0.003)


@pytest.mark.slow
def test_predicted_95_percent_error_covers_95_percent_of_true_errors() -> None:
    """Across independent calibrations, the true error at a fixed spot falls inside the predicted 95% radius
    about 95% of the time: the map is neither optimistic nor padded."""
    camera = paper_camera()
    probes = np.array([[20.0, 20.0], [195.0, 275.0], [380.0, 530.0], [10.0, 540.0], [300.0, 100.0]])
    probe_uv = camera.project(np.column_stack([probes, np.full(len(probes), MARKER_HEIGHT_CM)]))
    hits = total = 0
    for seed in range(150):
        s = survey_points(camera, rng=seed)
        result = calibrate_points(point_table(s.uv_px, s.xy_world_cm), (1280, 720), area_cm=PAPER_AREA)
        assert result.error_map is not None
        err = np.linalg.norm(result.calibration.pixel_to_world(probe_uv) - probes, axis=1)
        predicted = result.error_map.error_cm[
            np.round(probe_uv[:, 1]).astype(int), np.round(probe_uv[:, 0]).astype(int)
        ]
        hits += int(np.sum(err <= predicted))
        total += probes.shape[0]
    assert 0.90 <= hits / total <= 0.99


def test_error_grows_toward_the_far_edge_and_statistics_cover_the_working_area() -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=0)
    result = calibrate_points(point_table(s.uv_px, s.xy_world_cm), (1280, 720), area_cm=PAPER_AREA)
    emap = result.error_map
    assert emap is not None
    near = camera.project(np.array([[195.0, 30.0, 13.0]]))[0]
    far = camera.project(np.array([[195.0, 520.0, 13.0]]))[0]
    assert emap.error_cm[int(far[1]), int(far[0])] > emap.error_cm[int(near[1]), int(near[0])]
    inside = emap.error_cm[emap.in_area]
    assert emap.mean_cm == pytest.approx(float(inside.mean()))
    assert emap.max_cm == pytest.approx(float(inside.max()))
    assert emap.max_cm < 1.148  # the paper's Fig. 4 max
    mask = area_mask(result.calibration)
    assert mask[int(near[1]), int(near[0])] and not mask[5, 5]


def test_four_points_give_no_error_map_and_say_why() -> None:
    camera = paper_camera()
    xy = np.array([[0.0, 0.0], [390.0, 0.0], [390.0, 540.0], [0.0, 540.0]])
    uv = camera.project(np.column_stack([xy, np.full(4, 13.0)]))
    result = calibrate_points(point_table(uv, xy), (1280, 720))
    assert result.error_map is None
    assert any("no error map" in n for n in result.stats.notes)


@pytest.mark.slow
def test_error_map_png_is_written_with_the_area_and_points(tmp_path: Path) -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=0)
    result = calibrate_points(point_table(s.uv_px, s.xy_world_cm), (1280, 720), area_cm=PAPER_AREA)
    assert result.error_map is not None
    out = tmp_path / "map.png"
    background = np.full((720, 1280, 3), 90, np.uint8)
    write_error_map_png(out, result.error_map, result.calibration, points_uv_px=s.uv_px, background=background)
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 500 and image.shape[1] > 1000
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 100  # a colour scale, not a blank canvas


@pytest.mark.slow
def test_map_is_finer_than_its_grid_step() -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=2)
    result = calibrate_points(point_table(s.uv_px, s.xy_world_cm), (1280, 720), area_cm=PAPER_AREA)
    fine = predicted_error_map(result.fit.plane, 0.35, result.calibration, step_px=4)
    coarse = predicted_error_map(result.fit.plane, 0.35, result.calibration, step_px=16)
    assert fine.error_cm.shape == coarse.error_cm.shape == (720, 1280)
    both = fine.in_area & np.isfinite(fine.error_cm) & np.isfinite(coarse.error_cm)
    assert np.max(np.abs(fine.error_cm[both] - coarse.error_cm[both])) < 0.02
