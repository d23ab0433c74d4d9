"""The calibration, made from a rendered scene's files as a person would, reaches
its bars against the camera model that rendered the scene.

End to end through the command line: ``edge-ips sim render`` writes points.csv (34 survey points at 13 cm with 0.5 px
RMS noise), background.png and camera.json; ``edge-ips calibrate`` fits; the true error is measured over a dense grid
of the whole working area, at marker height, against the camera model in camera.json.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from edge.calibration import load_calibration
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM, load_camera
from edge.cli import main

pytestmark = pytest.mark.slow  # end to end, or long: left out of the quick loop (-m 'not slow')


def _run(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def true_error_cm(run_dir: Path, calibration: Path) -> np.ndarray:
    """Distance between grid points of the area and where the calibration maps their exact (distorted) pixels."""
    camera = load_camera(run_dir / "camera.json")
    cal = load_calibration(calibration, expected_size=(camera.width_px, camera.height_px))
    gx, gy = np.meshgrid(np.linspace(0, AREA_WIDTH_CM, 40), np.linspace(0, AREA_LENGTH_CM, 56))
    world = np.column_stack([gx.ravel(), gy.ravel()])
    uv = camera.project(np.column_stack([world, np.full(len(world), MARKER_HEIGHT_CM)]))
    return np.hypot(*(cal.pixel_to_world(uv) - world).T)


def _points_calibration(run_dir: Path, *extra: str) -> Path:
    out = run_dir / "calibration.json"
    _run(
        "calibrate",
        "points",
        str(run_dir / "points.csv"),
        "--out",
        str(out),
        "--image",
        str(run_dir / "background.png"),
        "--area",
        f"{AREA_WIDTH_CM}x{AREA_LENGTH_CM}",
        *extra,
    )
    return out


def test_points_calibration_from_rendered_scenes_reaches_the_bars(tmp_path):
    # The calibration's bars: mean <= 0.3 cm over the area; max <= 0.6 cm. The max is a noise statistic (0.5 px survey
    # noise); the calibration engineer's 500-seed benchmark finds it met on ~94 % of seeds, so it is asserted on
    # the median seed here, the mean on every seed.
    means, maxes = [], []
    for seed in range(5):
        run_dir = tmp_path / f"lab{seed}"
        _run("sim", "render", "lab", "--out", str(run_dir), "--frames", "1", "--seed", str(seed))
        err = true_error_cm(run_dir, _points_calibration(run_dir))
        means.append(err.mean())
        maxes.append(err.max())
    assert max(means) <= 0.3
    assert float(np.median(maxes)) <= 0.6


def test_lens_scene_calibrates_with_its_checkerboards(tmp_path):
    run_dir = tmp_path / "lens"
    _run("sim", "render", "lens", "--out", str(run_dir), "--frames", "1", "--seed", "0", "--kit")
    boards = sorted(str(p) for p in (run_dir / "boards").glob("board_*.png"))
    assert len(boards) >= 10
    intrinsics = run_dir / "intrinsics.json"
    _run("calibrate", "intrinsics", *boards, "--board", "9x6", "--square", "2.5", "--out", str(intrinsics))
    err = true_error_cm(run_dir, _points_calibration(run_dir, "--intrinsics", str(intrinsics)))
    assert err.mean() <= 0.3
    assert err.max() <= 0.6
    # and without undistorting, the same survey is visibly worse: the lens really distorts
    plain = true_error_cm(run_dir, _points_calibration(run_dir))
    assert plain.max() > 2 * err.max()


@pytest.mark.parametrize("name", ["lab", "lens"])
def test_kit_files_are_what_calibrate_reads(tmp_path, name):
    run_dir = tmp_path / name
    _run("sim", "render", name, "--out", str(run_dir), "--frames", "1", "--kit")
    kit_files = ("points.csv", "check.csv", "check_targets.png", "targets.png", "floor.png", "markers.csv")
    for file in (*kit_files, "background.png", "camera.json"):
        assert (run_dir / file).exists(), file
    assert (run_dir / "boards").exists() == (name == "lens")
    out = _points_calibration(run_dir)
    check = _run("calibrate", "check", str(out), str(run_dir / "check.csv"))
    assert "mean" in check


def test_the_kits_targets_photo_takes_the_clicked_survey_several_times_closer(tmp_path: Path) -> None:
    run_dir = tmp_path / "lab"
    _run("sim", "render", "lab", "--out", str(run_dir), "--frames", "1", "--kit")
    clicked = true_error_cm(run_dir, _points_calibration(run_dir)).mean()
    refined = true_error_cm(run_dir, _points_calibration(run_dir, "--refine-on", str(run_dir / "targets.png"))).mean()
    assert refined < 0.4 * clicked
