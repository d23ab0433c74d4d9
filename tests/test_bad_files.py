"""Every calibration, intrinsics, camera and configuration file a command reads is checked for shape and type: a
malformed one is one line naming the file and what is wrong, exit code 2, never a traceback (a traceback at
start-up exits 1, which systemd restarts every 3 s forever). Each malformation goes through the real CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner, Result

from edge.calibration.exact import exact_calibration
from edge.calibration.files import calibration_record, save_calibration
from edge.camera import PinholeCamera, save_camera
from edge.cli import main
from tests.support.calibration import DISTORTION, write_csv
from tests.support.runtime import write_clip

W, H = 320, 240
Json = dict[str, Any]


def run(*args: str | Path) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args], env={"EDGE_IPS_CONFIG": ""})


def assert_one_line_error(result: Result, *fragments: str) -> None:
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit)
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def small_camera() -> PinholeCamera:
    return PinholeCamera.look_at(
        (160.0, -150.0, 250.0), (160.0, 200.0, 0.0), width_px=W, height_px=H, dist_coeffs=DISTORTION
    )


@pytest.fixture(scope="module")
def kit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("kit")
    camera = small_camera()
    save_calibration(calibration_record(exact_calibration(camera), method="aruco"), d / "calibration.json")
    save_camera(camera, d / "camera.json")
    intrinsics = {
        "kind": "edge-ips/intrinsics",
        "version": 1,
        "image_width_px": W,
        "image_height_px": H,
        "camera_matrix": camera.camera_matrix.tolist(),
        "dist_coeffs": list(DISTORTION),
    }
    (d / "intrinsics.json").write_text(json.dumps(intrinsics))
    write_clip(d / "clip.avi", frames=10, width=W, height=H)
    rows = [f"{u},{v},{x},{y}" for (u, v), (x, y) in zip(_uv(camera), _xy(), strict=True)]
    write_csv(d / "points.csv", "u,v,x,y", rows)
    return {"dir": d}


def _xy() -> list[tuple[float, float]]:
    return [(x, y) for x in (40.0, 120.0, 200.0, 280.0) for y in (40.0, 140.0, 240.0, 340.0)]


def _uv(camera: PinholeCamera) -> list[tuple[float, float]]:
    import numpy as np

    xyz = np.array([[x, y, 13.0] for x, y in _xy()])
    return [(float(u), float(v)) for u, v in camera.project(xyz)]


def _with(base: Path, out: Path, mutate: Callable[[Json], object] | str | bytes) -> Path:
    """``base`` changed by ``mutate`` (a function editing the JSON object), or replaced by raw text/bytes."""
    if isinstance(mutate, str):
        out.write_text(mutate)
    elif isinstance(mutate, bytes):
        out.write_bytes(mutate)
    else:
        data = json.loads(base.read_text())
        mutate(data)
        out.write_text(json.dumps(data))
    return out


def _set(key: str, value: object) -> Callable[[Json], None]:
    def change(data: Json) -> None:
        node = data
        *parents, last = key.split(".")
        for part in parents:
            node = node[part]
        node[last] = value

    return change


def _drop(key: str) -> Callable[[Json], None]:
    return lambda data: data.pop(key)


CALIBRATION_CASES: list[tuple[str, Callable[[Json], object] | str | bytes, str]] = [
    ("homography 3x2", _set("homography_world_to_px", [[1, 2], [3, 4], [5, 6]]), "homography_world_to_px.0"),
    ("homography ragged", _set("homography_world_to_px", [[1, 0, 0], [0, 1], [0, 0, 1]]), "homography_world_to_px.1"),
    ("homography 4 rows", _set("homography_world_to_px", [[1, 0, 0]] * 4), "homography_world_to_px"),
    ("homography flat", _set("homography_world_to_px", [1, 0, 0, 0, 1, 0, 0, 0, 1]), "not 9"),
    ("homography text", _set("homography_world_to_px", "identity"), "homography_world_to_px"),
    ("homography null entry", _set("homography_world_to_px", [[1, 0, None], [0, 1, 0], [0, 0, 1]]), "0.2"),
    ("homography singular", _set("homography_world_to_px", [[1, 2, 3], [2, 4, 6], [0, 0, 1]]), "degenerate"),
    ("homography zeros", _set("homography_world_to_px", [[0, 0, 0]] * 3), "degenerate"),
    ("K ragged", _set("intrinsics.camera_matrix", [[300, 0, 160], [0, 300], [0, 0, 1]]), "camera_matrix.1"),
    ("K 2x2", _set("intrinsics.camera_matrix", [[300, 0], [0, 300]]), "camera_matrix"),
    ("K negative focal", _set("intrinsics.camera_matrix", [[-300, 0, 160], [0, -300, 120], [0, 0, 1]]), "focal"),
    ("K bottom row", _set("intrinsics.camera_matrix", [[300, 0, 160], [0, 300, 120], [1, 1, 1]]), "[0, 0, 1]"),
    ("K far principal point", _set("intrinsics.camera_matrix", [[300, 0, 9e6], [0, 300, 120], [0, 0, 1]]), "outside"),
    ("distortion 8 terms", _set("intrinsics.dist_coeffs", [0.0] * 8), "dist_coeffs"),
    ("distortion folds", _set("intrinsics.dist_coeffs", [1e300, 1e300, 0, 0, 0]), "cannot be inverted"),
    ("distortion text", _set("intrinsics.dist_coeffs", "barrel"), "dist_coeffs"),
    ("rvec 2 values", _set("camera_pose.rvec", [0.1, 0.2]), "camera_pose.rvec"),
    ("tvec text", _set("camera_pose.tvec", ["a", "b", "c"]), "camera_pose.tvec.0"),
    # finite, but cv2.Rodrigues makes a NaN rotation of it, and every pixel would map to NaN
    ("rvec 1e308", _set("camera_pose.rvec", [1e308, 0.0, 0.0]), "camera_pose.rvec: length 1e+308 rad"),
    ("rvec overflows", _set("camera_pose.rvec", [1e308, 1e308, 0.0]), "camera_pose.rvec"),
    ("rvec infinite", _set("camera_pose.rvec", [float("inf"), 0.0, 0.0]), "camera_pose.rvec.0"),
    ("rvec NaN", _set("camera_pose.rvec", [float("nan"), 0.0, 0.0]), "camera_pose.rvec.0"),
    ("tvec 1e308", _set("camera_pose.tvec", [0.0, 0.0, 1e308]), "camera_pose.tvec: length 1e+308 cm"),
    ("pose without intrinsics", _set("intrinsics", None), "needs intrinsics"),
    ("width zero", _set("image_width_px", 0), "image_width_px"),
    ("width fractional", _set("image_width_px", 320.5), "image_width_px"),
    ("width boolean", _set("image_width_px", True), "image_width_px"),
    ("width text", _set("image_width_px", "320"), "image_width_px"),
    ("height missing", _drop("image_height_px"), "image_height_px"),
    ("plane height absurd", _set("plane_height_cm", 1e9), "plane_height_cm"),
    ("area 3 values", _set("area_cm", [0, 0, 100]), "area_cm"),
    ("area inverted", _set("area_cm", [100, 100, 0, 0]), "working area"),
    ("unknown key", _set("surprise", 1), "surprise"),
    ("kind", _set("kind", "edge-ips/intrinsics"), "not an edge-ips calibration file"),
    ("version", _set("version", 7), "version 7"),
    ("NaN token", '{"kind": "edge-ips/calibration", "version": 1, "plane_height_cm": NaN}', "calibration file"),
    ("truncated", '{"kind": "edge-ips/calibration", "version": 1, "homography', "malformed JSON"),
    ("empty", "", "malformed JSON"),
    ("a list", "[1, 2, 3]", "JSON object"),
    ("binary", b"\x89PNG\r\n\x1a\n\x00\x00", "calibration file"),
]


@pytest.mark.parametrize(("name", "mutate", "fragment"), CALIBRATION_CASES, ids=[c[0] for c in CALIBRATION_CASES])
def test_start_refuses_a_malformed_calibration_in_one_line(
    kit: dict[str, Path], tmp_path: Path, name: str, mutate: Any, fragment: str
) -> None:
    d = kit["dir"]
    bad = _with(d / "calibration.json", tmp_path / "calibration.json", mutate)
    config = tmp_path / "edge-ips.toml"
    config.write_text(f'[camera]\nsource = "{d / "clip.avi"}"\n[calibration]\npath = "{bad}"\n')
    result = run("start", "--config", config, "--no-dashboard", "--http-port", "0", "--broker", "mqtt://127.0.0.1:9")
    assert_one_line_error(result, str(bad), fragment)


@pytest.mark.parametrize("broken", ["a malformed calibration", "a calibration that is not there"])
def test_a_bad_calibration_stops_start_before_it_makes_the_dashboard_token(
    kit: dict[str, Path], tmp_path: Path, private_state_dir: Path, broken: str
) -> None:
    # The token (made on a first start and printed with the page's address) is state: a start that is going to
    # refuse its calibration must not leave one behind, nor print an address nobody can open.
    d = kit["dir"]
    bad = tmp_path / "calibration.json"
    if broken == "a malformed calibration":
        _with(d / "calibration.json", bad, _set("camera_pose.rvec", [1e308, 0.0, 0.0]))
    config = tmp_path / "edge-ips.toml"
    config.write_text(f'[camera]\nsource = "{d / "clip.avi"}"\n[calibration]\npath = "{bad}"\n')
    result = run("start", "--config", config, "--http-port", "0", "--broker", "mqtt://127.0.0.1:9")
    assert_one_line_error(result, str(bad))
    assert "dashboard:" not in result.stdout
    assert not private_state_dir.exists() or not any(private_state_dir.iterdir())


@pytest.mark.parametrize(
    ("name", "mutate", "fragment"), CALIBRATION_CASES[:12], ids=[c[0] for c in CALIBRATION_CASES[:12]]
)
def test_check_and_track_refuse_a_malformed_calibration_in_one_line(
    kit: dict[str, Path], tmp_path: Path, name: str, mutate: Any, fragment: str
) -> None:
    d = kit["dir"]
    bad = _with(d / "calibration.json", tmp_path / "calibration.json", mutate)
    assert_one_line_error(run("calibrate", "check", bad, d / "points.csv"), str(bad), fragment)
    out = tmp_path / "poses.jsonl"
    assert_one_line_error(run("track", d / "clip.avi", "--calibration", bad, "--out", out), str(bad), fragment)


def test_the_good_files_of_these_tests_are_accepted(kit: dict[str, Path], tmp_path: Path) -> None:
    d = kit["dir"]
    check = run("calibrate", "check", d / "calibration.json", d / "points.csv")
    assert check.exit_code == 0, check.output
    assert "mean 0.0" in check.output  # the exact calibration maps its own points back
    points = run(
        "calibrate",
        "points",
        d / "points.csv",
        "--intrinsics",
        d / "intrinsics.json",
        "--out",
        tmp_path / "cal.json",
        "--no-outlier-test",
    )
    assert points.exit_code == 0, points.output
    tracked = run("track", d / "clip.avi", "--calibration", d / "camera.json", "--out", tmp_path / "poses.jsonl")
    assert tracked.exit_code == 0, tracked.output


def test_a_calibration_for_another_image_size_stops_start_in_one_line(kit: dict[str, Path], tmp_path: Path) -> None:
    d = kit["dir"]
    video = write_clip(tmp_path / "big.avi", frames=5, width=640, height=480)
    config = tmp_path / "edge-ips.toml"
    config.write_text(f'[camera]\nsource = "{video}"\n[calibration]\npath = "{d / "calibration.json"}"\n')
    result = run("start", "--config", config, "--no-dashboard", "--http-port", "0", "--broker", "mqtt://127.0.0.1:9")
    assert_one_line_error(result, "320x240", "640x480")


INTRINSICS_CASES: list[tuple[str, Callable[[Json], object] | str | bytes, str]] = [
    ("K ragged", _set("camera_matrix", [[300, 0, 160], [0, 300], [0, 0, 1]]), "camera_matrix.1"),
    ("K 3x2", _set("camera_matrix", [[300, 0], [0, 300], [0, 0]]), "camera_matrix.0"),
    ("K NaN", '{"kind": "edge-ips/intrinsics", "version": 1, "camera_matrix": [[NaN, 0, 0]]}', "intrinsics file"),
    ("K skewed", _set("camera_matrix", [[300, 1e9, 160], [0, 300, 120], [0, 0, 1]]), "skew"),
    ("K zero focal", _set("camera_matrix", [[0, 0, 160], [0, 300, 120], [0, 0, 1]]), "focal"),
    ("distortion folds", _set("dist_coeffs", [-3.0, 0, 0, 0, 0]), "cannot be inverted"),
    ("distortion 6 terms", _set("dist_coeffs", [0.0] * 6), "dist_coeffs"),
    ("width text", _set("image_width_px", "wide"), "image_width_px"),
    ("board text", _set("board", "9x6"), "board"),
    ("square negative", _set("square_cm", -2.5), "square_cm"),
    ("kind", _set("kind", "edge-ips/calibration"), "not an edge-ips intrinsics file"),
    ("not JSON", "camera_matrix = 1", "not JSON"),
]


@pytest.mark.parametrize(("name", "mutate", "fragment"), INTRINSICS_CASES, ids=[c[0] for c in INTRINSICS_CASES])
def test_calibrate_refuses_malformed_intrinsics_in_one_line(
    kit: dict[str, Path], tmp_path: Path, name: str, mutate: Any, fragment: str
) -> None:
    d = kit["dir"]
    bad = _with(d / "intrinsics.json", tmp_path / "intrinsics.json", mutate)
    result = run("calibrate", "points", d / "points.csv", "--intrinsics", bad, "--out", tmp_path / "cal.json")
    assert_one_line_error(result, str(bad), fragment)
    assert not (tmp_path / "cal.json").exists()


CAMERA_CASES: list[tuple[str, Callable[[Json], object] | str | bytes, str]] = [
    ("K ragged", _set("camera_matrix", [[300, 0, 160], [0, 300], [0, 0, 1]]), "camera_matrix.1"),
    ("K 3x2", _set("camera_matrix", [[300, 0], [0, 300], [0, 0]]), "camera_matrix.0"),
    ("K negative focal", _set("camera_matrix", [[-300, 0, 160], [0, 300, 120], [0, 0, 1]]), "focal"),
    ("rvec 4 values", _set("rvec", [0, 0, 0, 0]), "rvec"),
    ("rvec 1e308", _set("rvec", [1e308, 1e308, 0.0]), "rvec: length 1.41e+308 rad"),
    ("tvec null", _set("tvec", None), "tvec"),
    ("width float", _set("width_px", 320.0), "width_px"),
]


@pytest.mark.parametrize(("name", "mutate", "fragment"), CAMERA_CASES, ids=[c[0] for c in CAMERA_CASES])
def test_track_refuses_a_malformed_camera_file_in_one_line(
    kit: dict[str, Path], tmp_path: Path, name: str, mutate: Any, fragment: str
) -> None:
    d = kit["dir"]
    bad = _with(d / "camera.json", tmp_path / "camera.json", mutate)
    result = run("track", d / "clip.avi", "--calibration", bad, "--out", tmp_path / "poses.jsonl")
    assert_one_line_error(result, str(bad), fragment)


CONFIG_CASES = [
    ("rover colour above 255", "[[rovers]]\nid = 'red'\ncolor_bgr = [999, 0, 0]\n", "rovers.0.color_bgr.0"),
    ("rover colour negative", "[[rovers]]\nid = 'red'\ncolor_bgr = [0, -1, 0]\n", "rovers.0.color_bgr.1"),
    ("rover colour 2 values", "[[rovers]]\nid = 'red'\ncolor_bgr = [0, 0]\n", "rovers.0.color_bgr"),
    ("rover colour text", "[[rovers]]\nid = 'red'\ncolor_bgr = 'red'\n", "rovers.0.color_bgr"),
    (
        "front colour 4 values",
        "[[rovers]]\nid = 'r'\ncolor_bgr = [0, 0, 200]\nfront_color_bgr = [1, 2, 3, 4]\n",
        "rovers.0.front_color_bgr",
    ),
    ("front fraction 1", "[[rovers]]\nid = 'r'\ncolor_bgr = [0, 0, 200]\nfront_fraction = 1.0\n", "front_fraction"),
    ("rovers a number", "rovers = 3\n", "rovers"),
    ("rovers empty", "rovers = []\n", "rovers"),
    ("rover without colour", "[[rovers]]\nid = 'red'\n", "rovers.0.color_bgr"),
    ("camera an array", "[[camera]]\nsource = 'sim'\n", "camera"),
    ("camera width text", "[camera]\nwidth = 'wide'\n", "camera.width"),
    ("camera unknown key", "[camera]\nexposure = 3\n", "camera.exposure"),
    ("calibration path a table", "[calibration]\npath = {a = 1}\n", "calibration.path"),
    ("tracker unknown key", "[tracker]\nspeed = 3\n", "tracker"),
    # Numbers without a bound passed here and killed the tracker thread at its first frame (exit 1, a restart loop).
    ("tracker fps infinite", "[tracker]\nfps = inf\n", "tracker.fps"),
    ("tracker fps 1e308", "[tracker]\nfps = 1e308\n", "tracker.fps"),
    ("filter noise 1e308", "[tracker]\naccel_sigma_cm_s2 = 1e308\n", "tracker.accel_sigma_cm_s2"),
    ("pixel noise 1e308", "[tracker]\nmeasurement_sigma_px = 1e308\n", "tracker.measurement_sigma_px"),
    ("refresh infinite", "[tracker]\nbackground_refresh_s = inf\n", "tracker.background_refresh_s"),
    ("window margin 1e308", "[tracker]\nwindow_margin_cm = 1e308\n", "tracker.window_margin_cm"),
    ("area range inverted", "[tracker]\nacquire_area_range = [2.0, 0.5]\n", "tracker.acquire_area_range"),
    ("level range infinite", "[tracker]\nlevel_range = [0.4, inf]\n", "tracker.level_range"),
    ("camera gain beyond 32 bits", "[camera.controls]\ngain = 99999999999\n", "camera.controls.gain"),
    # a server that times out every request before it can arrive; a status loop without a pause
    ("request timeout 1e-300", "[http]\nrequest_timeout_s = 1e-300\n", "http.request_timeout_s"),
    ("status interval 1e-300", "[edge]\nstatus_interval_s = 1e-300\n", "edge.status_interval_s"),
    ("token too short", "[dashboard]\ntoken = 'abc'\n", "dashboard.token: at least 8 characters"),
    ("not TOML", "[camera\n", "invalid TOML"),
]


@pytest.mark.parametrize(("name", "text", "fragment"), CONFIG_CASES, ids=[c[0] for c in CONFIG_CASES])
def test_every_config_command_refuses_a_malformed_configuration_in_one_line(
    tmp_path: Path, name: str, text: str, fragment: str
) -> None:
    config = tmp_path / "edge-ips.toml"
    config.write_text(text)
    for args in (
        ["start", "--config", config, "--no-dashboard"],
        ["config", "show", "--config", config],
        ["doctor", "--config", config],
    ):
        assert_one_line_error(run(*args), str(config), fragment)


def test_a_configuration_that_is_not_text_is_one_line(tmp_path: Path) -> None:
    config = tmp_path / "edge-ips.toml"
    config.write_bytes(b"\xff\xfe[camera]\x00")
    assert_one_line_error(run("config", "show", "--config", config), str(config), "not UTF-8")


@pytest.mark.slow
def test_the_real_edge_ips_process_exits_2_without_a_traceback(kit: dict[str, Path], tmp_path: Path) -> None:
    """What systemd sees: exit status 2 (RestartPreventExitStatus=2 in deploy/edge-ips.service) and one line."""
    d = kit["dir"]
    bad = _with(d / "calibration.json", tmp_path / "calibration.json", CALIBRATION_CASES[0][1])
    config = tmp_path / "edge-ips.toml"
    config.write_text(f'[camera]\nsource = "{d / "clip.avi"}"\n[calibration]\npath = "{bad}"\n')
    env = {k: v for k, v in os.environ.items() if not k.startswith("EDGE_IPS_")}
    done = subprocess.run(
        [sys.executable, "-m", "edge.cli", "start", "--config", str(config), "--http-port", "0", "--no-dashboard"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and str(bad) in errors[0] and "homography_world_to_px" in errors[0]
