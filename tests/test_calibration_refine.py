"""Clicked survey points moved onto printed targets (`edge.calibration.refine`, `calibrate points --refine-on`):
on rendered photos with exact ground truth, on a real photograph, and every bad input through the command."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner, Result

from edge.calibration.points import calibrate_points, point_table
from edge.calibration.refine import refine_clicks
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM, PinholeCamera, paper_camera
from edge.cli import main
from edge.sim.targets import check_points, survey_points, survey_target_frame, targets_apart

REAL = Path(__file__).parent / "data" / "realdata"


def run(*args: str | Path) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def true_error_cm(camera: PinholeCamera, uv_px: np.ndarray, xy_cm: np.ndarray) -> float:
    """The mean distance over a dense grid of the area between each place and where a calibration fitted to the
    clicks ``uv_px`` maps its exact pixel."""
    fitted = calibrate_points(point_table(uv_px, xy_cm), (1280, 720), height_cm=MARKER_HEIGHT_CM).calibration
    gx, gy = np.meshgrid(np.linspace(0.0, AREA_WIDTH_CM, 30), np.linspace(0.0, AREA_LENGTH_CM, 40))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    exact = camera.project(np.column_stack([grid, np.full(len(grid), MARKER_HEIGHT_CM)]))
    return float(np.hypot(*(fitted.pixel_to_world(exact) - grid).T).mean())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clicks_half_a_pixel_off_are_moved_onto_their_targets_corners(seed: int) -> None:
    camera = paper_camera()
    survey = survey_points(camera, rng=seed)  # 0.5 px RMS clicks
    photo = survey_target_frame(camera, survey.xy_world_cm, rng=seed)
    refined = refine_clicks(photo, survey.uv_px)
    assert refined.found.all()
    before = np.hypot(*(survey.uv_px - survey.uv_true_px).T)
    after = np.hypot(*(refined.uv_px - survey.uv_true_px).T)
    assert np.sqrt(np.mean(after**2)) < 0.1 < 0.3 < np.sqrt(np.mean(before**2))
    assert after.max() < 0.25  # the far row's targets too, their squares 3 px tall
    assert np.allclose(refined.moved_px, np.hypot(*(refined.uv_px - survey.uv_px).T))


def test_a_calibration_from_refined_clicks_is_several_times_closer_to_the_truth() -> None:
    camera = paper_camera()
    raw, refined = [], []
    for seed in range(3):
        survey = survey_points(camera, rng=10 + seed)
        photo = survey_target_frame(camera, survey.xy_world_cm, rng=10 + seed)
        raw.append(true_error_cm(camera, survey.uv_px, survey.xy_world_cm))
        refined.append(true_error_cm(camera, refine_clicks(photo, survey.uv_px).uv_px, survey.xy_world_cm))
    assert np.mean(refined) < 0.4 * np.mean(raw)


def test_clicks_with_no_target_under_them_stay_as_clicked() -> None:
    camera = paper_camera()
    xy = np.array([[100.0, 100.0], [250.0, 300.0]])
    photo = survey_target_frame(camera, xy, rng=0)
    corners = camera.project(np.column_stack([xy, np.full(2, MARKER_HEIGHT_CM)]))
    card_edge = camera.project(np.array([[100.0 + 10.5, 100.0, MARKER_HEIGHT_CM]]))  # a straight edge, not an X
    plain_floor = np.array([[640.0, 420.0], [5.0, 5.0], [1279.0, 719.0]])  # the floor, the image's corners
    clicks = np.vstack([corners + 0.6, card_edge, plain_floor])
    refined = refine_clicks(photo, clicks)
    assert refined.found.tolist() == [True, True, False, False, False, False]
    assert np.array_equal(refined.uv_px[2:], clicks[2:])
    assert np.all(refined.moved_px[2:] == 0.0)


def test_corners_of_a_real_photographed_checkerboard_are_found_from_clicks_a_pixel_off() -> None:
    """OpenCV's own left01.jpg (a real camera's blur, noise and JPEG; no exact truth): clicks 0.5-1.4 px off the
    board's inner corners come back to where a click on the corner itself goes (the same saddle, whatever the start),
    and that agrees with OpenCV's own sub-pixel corners (findChessboardCorners + cornerSubPix, a different estimator
    with errors of its own) to about a tenth of a pixel."""
    gray = cv2.imread(str(REAL / "chessboard-9x6" / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    ok, corners = cv2.findChessboardCorners(gray, (9, 6))
    assert ok
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)
    opencv = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2).astype(np.float64)
    rng = np.random.default_rng(7)
    angle = rng.uniform(0.0, 2.0 * np.pi, len(opencv))
    radius = rng.uniform(0.5, 1.4, len(opencv))
    clicks = opencv + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    refined = refine_clicks(gray, clicks)
    on_corner = refine_clicks(gray, opencv)
    assert refined.found.all() and on_corner.found.all()
    assert np.hypot(*(refined.uv_px - on_corner.uv_px).T).max() < 0.02
    against_opencv = np.hypot(*(refined.uv_px - opencv).T)
    assert np.median(against_opencv) < 0.12 and against_opencv.max() < 0.3


def test_on_a_real_charuco_photo_refined_clicks_fit_as_well_as_opencvs_own_corners() -> None:
    """OpenCV's real ChArUco photo (a 4 cm board, its lens visibly distorting): its 24 inner corners as OpenCV's
    CharucoDetector finds them, clicked 0.5-1.4 px off. A plane fitted to the clicks misses them by 0.7 px RMS; to
    the refined clicks by what it misses OpenCV's own corners by (the lens, not the corners)."""
    photo = cv2.imread(str(REAL / "charuco-5x7" / "choriginal.jpg"))
    board = cv2.aruco.CharucoBoard((5, 7), 4.0, 2.0, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(photo)
    opencv = corners.reshape(-1, 2).astype(np.float64)
    world = board.getChessboardCorners()[ids.ravel()][:, :2] * [1.0, -1.0]
    rng = np.random.default_rng(3)
    angle, radius = rng.uniform(0.0, 2.0 * np.pi, len(opencv)), rng.uniform(0.5, 1.4, len(opencv))
    clicks = opencv + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    refined = refine_clicks(photo, clicks)
    assert refined.found.sum() >= len(opencv) - 2

    def sigma(uv: np.ndarray) -> float:
        fit = calibrate_points(point_table(uv, world), (640, 480), height_cm=0.0, detect_outliers=False)
        assert fit.stats.sigma_px is not None
        return fit.stats.sigma_px

    assert sigma(refined.uv_px) < 0.35 * sigma(clicks)
    assert sigma(refined.uv_px) < 1.2 * sigma(opencv)


@pytest.fixture(scope="module")
def kit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("targets")
    camera = paper_camera()
    survey = survey_points(camera, rng=3)
    survey.write_csv(d / "points.csv")
    cv2.imwrite(str(d / "targets.png"), survey_target_frame(camera, survey.xy_world_cm, rng=3))
    cv2.imwrite(str(d / "empty.png"), np.full((720, 1280, 3), 95, np.uint8))
    cv2.imwrite(str(d / "small.png"), np.full((480, 640, 3), 95, np.uint8))
    (d / "junk.png").write_bytes(b"not an image")
    check = check_points(camera, rng=4)
    check.write_csv(d / "check.csv")
    apart = check.xy_world_cm[targets_apart(check.xy_world_cm)]
    cv2.imwrite(str(d / "check_targets.png"), survey_target_frame(camera, apart, rng=4))
    return {"dir": d, "points": d / "points.csv", "targets": d / "targets.png", "check": d / "check.csv"}


def test_calibrate_points_refines_the_clicks_on_the_targets_photo(kit: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    result = run("calibrate", "points", kit["points"], "--refine-on", kit["targets"], "--out", out)
    assert result.exit_code == 0, result.output
    assert f"clicks refined on {kit['targets']}: 34 of 34 moved onto their targets' corners" in result.output
    assert "NOT REFINED" not in result.output
    plain = tmp_path / "plain.json"
    assert run("calibrate", "points", kit["points"], "--out", plain).exit_code == 0
    sigma = [json.loads(p.read_text())["fit"]["sigma_px"] for p in (plain, out)]
    assert sigma[1] < 0.5 * sigma[0]  # the fit's residuals: the clicks' noise is gone


def test_a_click_without_a_target_is_named_and_kept(kit: dict[str, Path], tmp_path: Path) -> None:
    lines = kit["points"].read_text().splitlines()
    header, first = lines[0], lines[1].split(",")
    cols = header.split(",")
    first[cols.index("u")] = str(float(first[cols.index("u")]) + 40.0)  # clicked 40 px beside its target
    moved = tmp_path / "points.csv"
    moved.write_text("\n".join([header, ",".join(first), *lines[2:]]) + "\n")
    result = run("calibrate", "points", moved, "--refine-on", kit["targets"], "--out", tmp_path / "c.json")
    assert result.exit_code == 0, result.output
    assert "33 of 34 moved" in result.output
    assert f"NOT REFINED {moved} row 1 (line 2): no target's corner within 3 px" in result.output


@pytest.mark.parametrize(
    ("photo", "fragment"),
    [
        ("empty.png", "no printed target's corner near any of the 34 clicks"),
        ("small.png", "is 640x480 but the points are for 1280x720 images"),
        ("junk.png", "cannot read image"),
        ("missing.png", "image not found"),
    ],
)
def test_a_bad_targets_photo_is_a_one_line_error(
    kit: dict[str, Path], tmp_path: Path, photo: str, fragment: str
) -> None:
    out = tmp_path / "c.json"
    result = run("calibrate", "points", kit["points"], "--refine-on", kit["dir"] / photo, "--out", out)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and fragment in lines[0], result.stderr
    assert not out.exists()


def test_calibrate_check_refines_the_check_points_so_it_reports_the_calibrations_error(
    kit: dict[str, Path], tmp_path: Path
) -> None:
    """Check points are clicked too, and their own half pixel is most of what a check reports; refined on their
    targets, what is left is the calibration's. Random check points too close for two cards carry no target: named,
    kept as measured."""
    cal = tmp_path / "cal.json"
    assert run("calibrate", "points", kit["points"], "--refine-on", kit["targets"], "--out", cal).exit_code == 0
    plain = run("calibrate", "check", cal, kit["check"], "--json")
    refined = run("calibrate", "check", cal, kit["check"], "--refine-on", kit["dir"] / "check_targets.png", "--json")
    assert plain.exit_code == 0 and refined.exit_code == 0, refined.output
    means = [json.loads(r.output)["mean_cm"] for r in (plain, refined)]
    assert means[1] < 0.5 * means[0]
    text = run("calibrate", "check", cal, kit["check"], "--refine-on", kit["dir"] / "check_targets.png")
    assert "check points refined on" in text.output
    missing = int((~targets_apart(check_points(paper_camera(), rng=4).xy_world_cm)).sum())
    assert text.output.count("NOT REFINED") == missing
    wrong = run("calibrate", "check", cal, kit["check"], "--refine-on", kit["targets"], "--refine-on", kit["targets"])
    assert wrong.exit_code == 2 and "one photo per board" in wrong.stderr
