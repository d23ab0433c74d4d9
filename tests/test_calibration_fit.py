"""Point-pair fitting: exactness, leave-one-out figures, the outlier test and its report, the survey layout."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.calibration.files import Calibration
from edge.calibration.homography import apply_homography, fit_plane
from edge.calibration.points import fit_points, point_table, validate_points
from edge.calibration.survey import grid_candidates, plan_survey
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, PinholeCamera, paper_camera
from edge.errors import CalibrationError
from edge.sim.targets import PAPER_AREA, survey_layout, survey_points

cameras = st.builds(
    lambda x, back, height, aim_y, hfov, roll, px, py: PinholeCamera.look_at(
        (x, -back, height), (195.0, aim_y, 0.0), hfov_deg=hfov, roll_deg=roll, principal_offset_px=(px, py)
    ),
    x=st.floats(120.0, 270.0),
    back=st.floats(150.0, 300.0),
    height=st.floats(230.0, 330.0),
    aim_y=st.floats(150.0, 260.0),
    hfov=st.floats(68.0, 80.0),
    roll=st.floats(-3.0, 3.0),
    px=st.floats(-30.0, 30.0),
    py=st.floats(-30.0, 30.0),
)


@pytest.mark.slow
@settings(max_examples=25, deadline=None)
@given(camera=cameras)
def test_noise_free_points_give_the_exact_mapping_for_any_oblique_camera(camera: PinholeCamera) -> None:
    xy = grid_candidates(390.0, 540.0, 90.0)
    uv = camera.project(np.column_stack([xy, np.full(len(xy), 13.0)]))
    inside = (uv[:, 0] > 0) & (uv[:, 0] < 1279) & (uv[:, 1] > 0) & (uv[:, 1] < 719)
    fit = fit_points(point_table(uv[inside], xy[inside]), (1280, 720))
    cal = Calibration(fit.plane.g, 1280, 720, 13.0, PAPER_AREA)
    probe = np.array([[10.0, 10.0], [200.0, 300.0], [380.0, 530.0]])
    probe_uv = camera.project(np.column_stack([probe, np.full(3, 13.0)]))
    np.testing.assert_allclose(cal.pixel_to_world(probe_uv), probe, atol=1e-5)
    np.testing.assert_allclose(cal.world_to_pixel(probe), probe_uv, atol=1e-5)
    assert not fit.rejected


def test_fit_minimises_pixel_residuals_not_world_residuals() -> None:
    """The fit is world -> image (MLE for pixel noise): its pixel residuals are orthogonal to the model's tangent
    space, so refitting from the fitted mapping changes nothing, and the residual sum is no larger than the
    residuals of the exact (true) mapping."""
    camera = paper_camera()
    survey = survey_points(camera, rng=3)
    fit = fit_plane(survey.xy_world_cm, survey.uv_px)
    true_g = camera.plane_homography(13.0)
    rss_fit = float(np.sum(fit.residuals_px**2))
    rss_true = float(np.sum((survey.uv_px - apply_homography(true_g, survey.xy_world_cm)) ** 2))
    assert rss_fit <= rss_true
    j = fit.param_jacobian_px(survey.xy_world_cm).reshape(-1, 8)
    gradient = j.T @ fit.residuals_px.reshape(-1)
    assert np.linalg.norm(gradient) < 1e-6 * np.linalg.norm(j) * np.linalg.norm(fit.residuals_px)


def test_sigma_estimate_matches_the_measuring_noise() -> None:
    camera = paper_camera()
    sigmas = [fit_plane(s.xy_world_cm, s.uv_px).sigma_px for s in (survey_points(camera, rng=k) for k in range(30))]
    assert np.mean(sigmas) == pytest.approx(0.5 / math.sqrt(2.0), rel=0.1)  # 0.5 px RMS radial = 0.354 per axis


@pytest.mark.slow
def test_leave_one_out_errors_are_honest_predictions() -> None:
    """LOO errors exceed the fit's own residuals (a point cannot pull the fit toward itself) and match the
    distances measured on independent check points of the same quality."""
    camera = paper_camera()
    loo_means, resid_means = [], []
    for seed in range(10):
        s = survey_points(camera, rng=seed)
        fit = fit_points(point_table(s.uv_px, s.xy_world_cm), (1280, 720))
        stats = fit.loo_stats_cm()
        assert stats is not None
        assert fit.loo_error_cm is not None
        assert np.all(fit.loo_error_cm[fit.used] >= 0)
        loo_means.append(stats[0])
        resid_means.append(float(fit.residual_cm[fit.used].mean()))
    assert np.mean(loo_means) > np.mean(resid_means)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("index", "offset_px"),
    [(0, (6.0, 0.0)), (5, (0.0, -3.0)), (17, (6.0, 6.0)), (30, (-10.0, 2.0)), (33, (0.0, 40.0))],
)
def test_a_mis_measured_point_is_rejected_and_reported(index: int, offset_px: tuple[float, float]) -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=100 + index)
    uv = s.uv_px.copy()
    uv[index] += offset_px
    fit = fit_points(point_table(uv, s.xy_world_cm, source="survey.csv"), (1280, 720))
    assert [r.index for r in fit.rejected] == [index]
    r = fit.rejected[0]
    assert r.row == index + 1 and r.line == index + 2
    assert r.score > 4.0
    assert r.loo_residual_px == pytest.approx(math.hypot(*offset_px), rel=0.35, abs=1.0)
    assert not fit.used[index] and fit.n_used == 33


def test_a_mis_surveyed_world_position_is_rejected() -> None:
    """A target put down half a grid cell (15 cm) off its mark is found as surely as a mis-clicked pixel."""
    camera = paper_camera()
    s = survey_points(camera, rng=7)
    xy = s.xy_world_cm.copy()
    xy[12, 0] += 15.0
    fit = fit_points(point_table(s.uv_px, xy), (1280, 720))
    assert [r.index for r in fit.rejected] == [12]


@pytest.mark.slow
def test_two_bad_points_are_both_found() -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=11)
    uv = s.uv_px.copy()
    uv[3] += (8.0, 0.0)
    uv[20] += (0.0, 9.0)
    fit = fit_points(point_table(uv, s.xy_world_cm), (1280, 720))
    assert sorted(r.index for r in fit.rejected) == [3, 20]


@pytest.mark.slow
def test_rejected_points_do_not_spoil_the_mapping() -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=5)
    uv = s.uv_px.copy()
    uv[8] += (25.0, -25.0)
    robust = fit_points(point_table(uv, s.xy_world_cm), (1280, 720))
    naive = fit_points(point_table(uv, s.xy_world_cm), (1280, 720), detect_outliers=False)
    probe = s.uv_true_px
    truth = s.xy_world_cm
    err_robust = np.linalg.norm(apply_homography(np.linalg.inv(robust.plane.g), probe) - truth, axis=1).max()
    err_naive = np.linalg.norm(apply_homography(np.linalg.inv(naive.plane.g), probe) - truth, axis=1).max()
    assert err_robust < 0.6 < err_naive


@pytest.mark.slow
def test_clean_surveys_rarely_lose_a_point() -> None:
    """The test's false-alarm rate is about 1% per calibration by design; over 40 clean surveys at most 4."""
    camera = paper_camera()
    flagged = sum(
        bool(fit_points(point_table(s.uv_px, s.xy_world_cm), (1280, 720)).rejected)
        for s in (survey_points(camera, rng=500 + k) for k in range(40))
    )
    assert flagged <= 4


@pytest.mark.slow
def test_too_many_inconsistent_points_is_an_error_not_a_silent_fit() -> None:
    camera = paper_camera()
    s = survey_points(camera, rng=1)
    uv = s.uv_px.copy()
    rng = np.random.default_rng(0)
    bad = rng.choice(34, size=12, replace=False)
    uv[bad] += rng.normal(0.0, 30.0, (12, 2))
    with pytest.raises(CalibrationError, match="too many inconsistent points"):
        fit_points(point_table(uv, s.xy_world_cm, source="bad.csv"), (1280, 720))


@pytest.mark.parametrize(
    ("uv", "xy", "message"),
    [
        ([[0, 0], [1, 1], [2, 5]], [[0, 0], [1, 0], [0, 1]], "need at least 4 points, found 3"),
        ([[0, 0], [100, 0], [200, 0], [300, 0]], [[0, 0], [1, 0], [0, 1], [1, 1]], "pixel points lie on one line"),
        ([[0, 0], [100, 5], [200, 90], [30, 300]], [[0, 0], [1, 1], [2, 2], [3, 3]], "world points lie on one line"),
        (
            [[0, 0], [100, 5], [200, 90], [30, 300], [400, 400]],
            [[0, 0], [1, 1], [2, 2], [3, 3], [5, 0]],
            "all world points but points row 5",
        ),
        ([[0, 0], [100, 5], [200, 90], [30, 300]], [[0, 0], [1, 0], [0, 1], [1, 0]], "row 4 .*duplicate world point"),
        ([[0, 0], [100, 5], [100, 5], [30, 300]], [[0, 0], [1, 0], [0, 1], [1, 1]], "row 3 .*duplicate pixel"),
        ([[0, 0], [100, 5], [1300, 90], [30, 300]], [[0, 0], [1, 0], [0, 1], [1, 1]], "row 3 .*outside the 1280x720"),
    ],
)
def test_bad_point_sets_are_refused_with_the_row(uv: list, xy: list, message: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(CalibrationError, match=message):
        validate_points(point_table(np.asarray(uv, float), np.asarray(xy, float)), (1280, 720))


def test_survey_layout_favours_the_far_edge_and_beats_an_even_spread() -> None:
    camera = paper_camera()
    layout = survey_layout(camera)
    assert layout.shape == (34, 2)
    assert len({tuple(p) for p in layout}) == 34
    assert np.all(np.mod(layout, 30.0) == 0.0)
    assert np.all((layout >= 0) & (layout <= [AREA_WIDTH_CM, AREA_LENGTH_CM]))
    assert np.sum(layout[:, 1] >= 450) > np.sum(layout[:, 1] <= 90)  # more points where resolution is lowest
    even = np.asarray([(x, y) for y in (0, 90, 180, 270, 360, 450, 540) for x in (0, 90, 210, 300, 390)][:34], float)

    def worst_predicted(xy: np.ndarray) -> float:
        uv = camera.project(np.column_stack([xy, np.full(len(xy), 13.0)]))
        fit = fit_plane(xy, uv)
        area = np.array([[x, y] for x in (0.0, AREA_WIDTH_CM) for y in (0.0, AREA_LENGTH_CM)])
        return float(np.max(np.trace(fit.world_covariance(area, 1.0), axis1=1, axis2=2)))

    assert worst_predicted(layout) < 0.8 * worst_predicted(even)


def test_plan_survey_refuses_impossible_requests() -> None:
    cand = grid_candidates(60.0, 60.0, 30.0)
    with pytest.raises(CalibrationError, match="cannot choose 20 survey points out of 9"):
        plan_survey(paper_camera().plane_homography(13.0), cand, (0, 0, 60, 60), 20)


def test_a_minimal_layout_still_gives_a_complete_record() -> None:
    """Five points, three on a line: some points cannot be cross-checked; the file must still be written."""
    from edge.calibration.points import calibrate_points

    camera = paper_camera()
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [50.0, 300.0], [300.0, 400.0]])
    uv = camera.project(np.column_stack([xy, np.full(5, 13.0)])) + np.random.default_rng(0).normal(0, 0.3, (5, 2))
    result = calibrate_points(point_table(uv, xy), (1280, 720))
    assert any("no outlier test" in n for n in result.stats.notes)
    assert result.error_map is not None
    assert '"kind":"edge-ips/calibration"' in result.record.model_dump_json()
