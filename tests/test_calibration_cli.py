"""`edge-ips calibrate points|intrinsics|aruco|check` end to end, and every bad input a user can give it."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner, Result

from edge.camera import paper_camera
from edge.cli import main
from edge.sim.targets import aruco_floor_frame, check_points, checkerboard_views, survey_points, write_markers_csv
from tests.support.calibration import DISTORTION, write_csv


def run(*args: str | Path) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_user_error(result: Result, *fragments: str) -> None:
    """Exit code 2, one line on stderr, naming what is wrong; no traceback."""
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("Error: ")
    assert "Traceback" not in result.output
    for f in fragments:
        assert f in lines[0], lines[0]


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("scene")
    camera = paper_camera()
    survey_points(camera, rng=0).write_csv(d / "points.csv")
    check_points(camera, rng=1).write_csv(d / "check.csv")
    frame = aruco_floor_frame(camera, rng=2)
    cv2.imwrite(str(d / "floor.png"), frame.image)
    write_markers_csv(d / "markers.csv", frame.markers)
    return {
        "dir": d,
        "points": d / "points.csv",
        "check": d / "check.csv",
        "floor": d / "floor.png",
        "markers": d / "markers.csv",
    }


@pytest.mark.parametrize("command", [[], ["points"], ["intrinsics"], ["aruco"], ["check"]])
def test_every_calibrate_command_has_help_with_an_example(command: list[str]) -> None:
    result = run("calibrate", *command, "--help")
    assert result.exit_code == 0
    assert "Example:" in result.output and "edge-ips calibrate" in result.output


@pytest.mark.slow
def test_points_writes_calibration_and_error_map_and_reports_figures(scene: dict[str, Path], tmp_path: Path) -> None:
    out, png = tmp_path / "calibration.json", tmp_path / "map.png"
    result = run(
        "calibrate",
        "points",
        scene["points"],
        "--out",
        out,
        "--image",
        scene["floor"],
        "--error-map",
        png,
        "--area",
        "391.5x549.5",
    )
    assert result.exit_code == 0, result.output
    assert "34 used, 0 rejected" in result.output
    assert "leave-one-out error: mean" in result.output and "max" in result.output
    assert f"-> {png}" in result.output and f"wrote {out}" in result.output
    assert json.loads(out.read_text())["kind"] == "edge-ips/calibration"
    assert cv2.imread(str(png)) is not None


@pytest.mark.slow
def test_points_reports_the_rejected_row(scene: dict[str, Path], tmp_path: Path) -> None:
    lines = scene["points"].read_text().splitlines()
    u, v, x, y = (float(f) for f in lines[8].split(","))
    lines[8] = f"{u + 7.5:.3f},{v - 5.0:.3f},{x:g},{y:g}"
    bad = write_csv(tmp_path / "survey.csv", lines[0], lines[1:])
    result = run("calibrate", "points", bad, "--out", tmp_path / "c.json")
    assert result.exit_code == 0, result.output
    assert f"REJECTED {bad} row 8 (line 9)" in result.output
    assert "33 used, 1 rejected" in result.output
    saved = json.loads((tmp_path / "c.json").read_text())
    assert [r["row"] for r in saved["rejected"]] == [8]
    assert [p["used"] for p in saved["points"]].count(False) == 1


@pytest.mark.slow
def test_check_reports_each_point_and_json_summary(scene: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "calibration.json"
    assert run("calibrate", "points", scene["points"], "--out", out).exit_code == 0
    text = run("calibrate", "check", out, scene["check"])
    assert text.exit_code == 0
    assert "20 check points" in text.output and "mean" in text.output and "max" in text.output
    result = run("calibrate", "check", out, scene["check"], "--json")
    assert result.exit_code == 0
    summary = json.loads(result.stdout)
    assert summary["n"] == 20 and 0 < summary["mean_cm"] <= summary["max_cm"] < 3.0
    assert len(summary["points"]) == 20 and summary["points"][0]["row"] == 1


@pytest.mark.slow
def test_intrinsics_then_points_with_lens(tmp_path: Path) -> None:
    camera = paper_camera(DISTORTION)
    paths = checkerboard_views(camera, rng=9).write(tmp_path / "boards")
    intr = tmp_path / "intrinsics.json"
    result = run("calibrate", "intrinsics", *paths, "--board", "9x6", "--square", "2.5", "--out", intr)
    assert result.exit_code == 0, result.output
    assert "found in 14 of 14 images" in result.output and "RMS" in result.output and f"wrote {intr}" in result.output
    survey_points(camera, rng=3).write_csv(tmp_path / "points.csv")
    result = run("calibrate", "points", tmp_path / "points.csv", "--intrinsics", intr, "--out", tmp_path / "c.json")
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "c.json").read_text())["intrinsics"]["dist_coeffs"][0] == pytest.approx(
        -0.12, abs=0.01
    )


def test_aruco_calibrates_without_clicking(scene: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "aruco.json"
    result = run("calibrate", "aruco", scene["floor"], "--markers", scene["markers"], "--out", out)
    assert result.exit_code == 0, result.output
    assert "found 12 of 12 markers" in result.output and "focal length estimated" in result.output
    assert "leave-one-marker-out error: mean" in result.output
    check = run("calibrate", "check", out, scene["check"], "--json")
    assert json.loads(check.stdout)["mean_cm"] < 1.5


# -- section 4: bad input ----------------------------------------------------------------------------------------
GOOD_ROWS = ["100,600,0,0", "1180,600,390,0", "900,120,390,540", "380,120,0,540", "640,300,195,270"]


@pytest.mark.parametrize(
    ("header", "rows", "fragments"),
    [
        ("u,v,x,y", [*GOOD_ROWS[:2], "900,120,390", *GOOD_ROWS[3:]], ["row 3 (line 4)", "expected 4 fields"]),
        ("u,v,x,y", [*GOOD_ROWS[:3], "380,abc,0,540", GOOD_ROWS[4]], ["row 4 (line 5)", "v is not a number: 'abc'"]),
        ("u,v,x,y", [GOOD_ROWS[0], "nan,600,390,0", *GOOD_ROWS[2:]], ["row 2 (line 3)", "u is not a finite number"]),
        ("u,v,x,y", [GOOD_ROWS[0], "1180,600,inf,0", *GOOD_ROWS[2:]], ["row 2 (line 3)", "x is not a finite number"]),
        ("u,v,x,y", GOOD_ROWS[:3], ["need at least 4 points, found 3"]),
        ("u,v,x,y", [], ["need at least 4 points, found 0"]),
        ("u,v,x,z", GOOD_ROWS, ["line 1", "header must name the columns u,v,x,y", "missing y"]),
        ("u,v,x,y", [*GOOD_ROWS[:4], "100,600,0,0"], ["row 5 (line 6)", "duplicate world point (0, 0) of row 1"]),
        ("u,v,x,y", [*GOOD_ROWS[:4], "1500,300,195,270"], ["row 5 (line 6)", "outside the 1280x720 image"]),
        ("u,v,x,y", [*GOOD_ROWS[:4], "640,-3,195,270"], ["row 5 (line 6)", "outside the 1280x720 image"]),
        (
            "u,v,x,y",
            ["100,600,0,0", "200,500,10,10", "300,400,20,20", "400,300,30,30"],
            ["world points lie on one line"],
        ),
    ],
)
def test_bad_points_csv_is_a_one_line_error_naming_file_and_row(
    tmp_path: Path, header: str, rows: list[str], fragments: list[str]
) -> None:
    path = write_csv(tmp_path / "points.csv", header, rows)
    result = run("calibrate", "points", path, "--out", tmp_path / "c.json")
    assert_user_error(result, str(path), *fragments)
    assert not (tmp_path / "c.json").exists()


def test_empty_and_missing_points_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    assert_user_error(run("calibrate", "points", empty, "--out", tmp_path / "c.json"), str(empty), "empty file")
    missing = tmp_path / "missing.csv"
    assert_user_error(run("calibrate", "points", missing, "--out", tmp_path / "c.json"), str(missing), "cannot read")
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    assert_user_error(run("calibrate", "points", binary, "--out", tmp_path / "c.json"), str(binary), "not a text")


def test_unreadable_reference_image(tmp_path: Path) -> None:
    points = write_csv(tmp_path / "points.csv", "u,v,x,y", GOOD_ROWS)
    junk = tmp_path / "reference.png"
    junk.write_bytes(b"this is not a png")
    assert_user_error(run("calibrate", "points", points, "--image", junk, "--out", tmp_path / "c.json"), str(junk))


def test_non_finite_plane_height_is_refused(scene: dict[str, Path], tmp_path: Path) -> None:
    result = run("calibrate", "points", scene["points"], "--height", "nan", "--out", tmp_path / "c.json")
    assert_user_error(result, "plane height must be a finite number")
    result = run(
        "calibrate",
        "aruco",
        scene["floor"],
        "--markers",
        scene["markers"],
        "--height",
        "inf",
        "--out",
        tmp_path / "a.json",
    )
    assert_user_error(result, "plane height must be a finite number")


@pytest.mark.parametrize("size", ["1280", "axb", "0x720", "1280x-5", "infx720", "nanx720"])
def test_bad_size_option(tmp_path: Path, size: str) -> None:
    points = write_csv(tmp_path / "points.csv", "u,v,x,y", GOOD_ROWS)
    assert_user_error(run("calibrate", "points", points, "--size", size, "--out", tmp_path / "c.json"), "--size")


@pytest.mark.slow
def test_board_not_found_names_the_image(tmp_path: Path) -> None:
    paths = checkerboard_views(paper_camera(), n_views=5, rng=4).write(tmp_path)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((720, 1280, 3), 128, np.uint8))
    result = run("calibrate", "intrinsics", *paths, blank, "--out", tmp_path / "i.json")
    assert_user_error(result, str(blank), "no 9x6 checkerboard found")
    unreadable = tmp_path / "broken.png"
    unreadable.write_bytes(b"\x89PNG broken")
    assert_user_error(run("calibrate", "intrinsics", unreadable, "--out", tmp_path / "i.json"), str(unreadable))
    assert_user_error(run("calibrate", "intrinsics", *paths, "--board", "9by6", "--out", tmp_path / "i.json"), "9by6")


def test_aruco_bad_inputs(scene: dict[str, Path], tmp_path: Path) -> None:
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((720, 1280, 3), 100, np.uint8))
    assert_user_error(
        run("calibrate", "aruco", blank, "--markers", scene["markers"], "--out", tmp_path / "a.json"),
        str(blank),
        "no DICT_4X4_50 ArUco markers found",
    )
    bad = write_csv(tmp_path / "markers.csv", "id,x,y,z,size", ["0,45,45,0,25", "1,oops,45,0,25"])
    assert_user_error(
        run("calibrate", "aruco", scene["floor"], "--markers", bad, "--out", tmp_path / "a.json"),
        str(bad),
        "row 2 (line 3)",
    )


def test_check_refuses_a_bad_calibration_and_bad_points(scene: dict[str, Path], tmp_path: Path) -> None:
    cal = tmp_path / "calibration.json"
    assert run("calibrate", "points", scene["points"], "--out", cal).exit_code == 0
    data = json.loads(cal.read_text())
    data["version"] = 7
    future = tmp_path / "future.json"
    future.write_text(json.dumps(data))
    assert_user_error(
        run("calibrate", "check", future, scene["check"]), str(future), "unknown calibration file version 7"
    )
    outside = write_csv(tmp_path / "check.csv", "u,v,x,y", ["640,360,195,270", "2000,360,195,270"])
    assert_user_error(run("calibrate", "check", cal, outside), str(outside), "row 2 (line 3)", "outside")
