"""The wide arena: one world seen by several cameras, rendered to files and as live sources; the whole offline chain
(calibrate each board from its survey points, track each video into detections, fuse) against the world's truth."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from edge.board_messages import parse_detections
from edge.calibration.points import read_points_csv
from edge.calibration.refine import refine_clicks
from edge.camera import load_camera
from edge.cli import main
from edge.errors import SimulationError
from edge.messages import parse_pose
from edge.sim.wide import build_wide, regions
from edge.sim.wide_source import WideCameraSource, parse_wide

FRAMES = 75
ROVERS = 6


def invoke(*args: str) -> str:
    result = CliRunner().invoke(main, list(args), catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def wide(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wide")
    invoke(
        "sim",
        "render",
        "wide",
        "--cameras",
        "2",
        "--rovers",
        str(ROVERS),
        "--frames",
        str(FRAMES),
        "--seed",
        "2",
        "--out",
        str(out),
    )
    return out


def _truth(path: Path) -> dict[tuple[int, str], tuple[float, float]]:
    with path.open() as f:
        return {(int(r["frame"]), r["id"]): (float(r["x"]), float(r["y"])) for r in csv.DictReader(f)}


@pytest.mark.slow
def test_one_truth_for_the_arena_and_a_directory_per_camera(wide: Path) -> None:
    with (wide / "truth.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["frame", "id", "x", "y", "theta", "vx", "vy"]
    assert len(rows) == FRAMES * ROVERS
    layout = json.loads((wide / "wide.json").read_text())
    assert [c["name"] for c in layout["cameras"]] == ["cam1", "cam2"]
    assert layout["cameras"][0]["phase_s"] == 0.0 and layout["cameras"][1]["phase_s"] != 0.0
    for cam in layout["cameras"]:
        where = wide / cam["name"]
        for name in (
            "video.mp4",
            "points.csv",
            "targets.png",
            "check.csv",
            "background.png",
            "camera.json",
            "rovers.toml",
        ):
            assert (where / name).is_file(), name
        video = cv2.VideoCapture(str(where / "video.mp4"))
        assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == FRAMES
        video.release()
        # the survey is in the shared floor frame, inside this camera's region, and consistent with its camera
        points = read_points_csv(where / "points.csv")
        x0, y0, x1, y1 = cam["region_cm"]
        assert np.all((points.xy_world_cm >= [x0, y0]) & (points.xy_world_cm <= [x1, y1]))
        camera = load_camera(where / "camera.json")
        exact = camera.project(np.column_stack([points.xy_world_cm, np.full(len(points), 13.0)]))
        click_px = np.hypot(*(points.uv_px - exact).T)
        assert 0.2 < float(np.sqrt(np.mean(click_px**2))) < 0.9  # 0.5 px RMS click noise
        # the targets under the clicks (a far corner's, its squares 2 px tall, may be too small to find: kept)
        refined = refine_clicks(cv2.imread(str(where / "targets.png")), points.uv_px)
        moved = refined.uv_px[refined.found] - exact[refined.found]
        assert refined.found.mean() > 0.9 and float(np.sqrt(np.mean(np.sum(moved**2, axis=1)))) < 0.15


def test_neighbouring_regions_overlap_and_cover_the_arena() -> None:
    for n in (2, 3, 4):
        boxes = regions(n, (0.0, 0.0, 800.0, 550.0))
        xs, ys = np.meshgrid(np.linspace(0, 800, 41), np.linspace(0, 550, 28))
        covered = np.zeros_like(xs, dtype=int)
        for x0, y0, x1, y1 in boxes:
            covered += (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
        assert covered.min() >= 1
        assert (covered >= 2).mean() > 0.1  # a strip of 100 cm along every seam (1/8 of the arena with two)


def test_every_region_is_whole_in_its_cameras_image() -> None:
    setup = build_wide(4, seed=1)
    for cam in setup.cameras:
        x0, y0, x1, y1 = cam.region_cm
        corners = np.array([[x0, y0, 13.0], [x1, y0, 13.0], [x1, y1, 13.0], [x0, y1, 13.0]])
        uv = cam.camera.project(corners)
        assert np.all((uv >= 0) & (uv <= [1279, 719]))


@pytest.mark.slow
def test_the_cameras_expose_the_one_world_at_their_own_instants(wide: Path, tmp_path: Path) -> None:
    """Camera 2's detections, compared with the world at cam1's instants, lag or lead by camera 2's phase."""
    layout = json.loads((wide / "wide.json").read_text())
    phase = layout["cameras"][1]["phase_s"]
    assert abs(phase) > 0.005  # this seed's camera 2 is exposed 10 ms after cam1
    cam2 = wide / "cam2"
    out = tmp_path / "cam2.jsonl"
    invoke(
        "track",
        str(cam2 / "video.mp4"),
        "--calibration",
        str(cam2 / "camera.json"),
        "--config",
        str(cam2 / "rovers.toml"),
        "--background",
        str(cam2 / "background.png"),
        "--detections",
        "--out",
        str(out),
    )
    world = build_wide(2, seed=2, rovers=ROVERS).world()
    ve, vv = 0.0, 0.0
    for line in out.read_bytes().splitlines():
        d = parse_detections(line)
        at_shared = world.state_at(d.frame / 30.0).by_id()
        for r in d.rovers:
            truth = at_shared[r.id]
            ve += truth.vx_cm_s * (r.x - truth.x_cm) + truth.vy_cm_s * (r.y - truth.y_cm)
            vv += truth.vx_cm_s**2 + truth.vy_cm_s**2
    assert vv > 0
    assert ve / vv == pytest.approx(phase, abs=0.002)  # the position error along the motion is the phase


@pytest.mark.slow
def test_calibrated_tracked_and_fused_the_boards_give_one_map_of_the_world(wide: Path, tmp_path: Path) -> None:
    detections = []
    for cam in ("cam1", "cam2"):
        where = wide / cam
        invoke(
            "calibrate",
            "points",
            str(where / "points.csv"),
            "--out",
            str(tmp_path / f"{cam}.json"),
            "--image",
            str(where / "background.png"),
        )
        det = tmp_path / f"{cam}.jsonl"
        invoke(
            "track",
            str(where / "video.mp4"),
            "--calibration",
            str(tmp_path / f"{cam}.json"),
            "--config",
            str(where / "rovers.toml"),
            "--background",
            str(where / "background.png"),
            "--detections",
            "--out",
            str(det),
        )
        detections.append(det)
    output = invoke("fuse", *map(str, detections), "--out", str(tmp_path / "poses.jsonl"))
    assert "cam2: clock offset" in output
    truth = _truth(wide / "truth.csv")
    errors = []
    for line in (tmp_path / "poses.jsonl").read_bytes().splitlines():
        pose = parse_pose(line)
        x, y = truth[(pose.frame, pose.id)]
        errors.append(math.hypot(pose.x - x, pose.y - y))
    assert len(errors) > 0.9 * FRAMES * ROVERS  # every rover, nearly every frame
    assert float(np.mean(errors)) < 0.5
    assert max(errors) < 3.0  # no rover ever mistaken for another (they are 80 cm apart and more)


def test_render_wide_refuses_what_it_cannot_build(tmp_path: Path) -> None:
    runner = CliRunner()
    five = runner.invoke(main, ["sim", "render", "wide", "--cameras", "5", "--out", str(tmp_path / "a")])
    assert five.exit_code == 2 and "--cameras" in five.output
    lab = runner.invoke(main, ["sim", "render", "lab", "--cameras", "2", "--out", str(tmp_path / "b")])
    assert lab.exit_code == 2 and "--cameras is for the wide scenario" in lab.output
    crowd = runner.invoke(main, ["sim", "render", "wide", "--rovers", "65", "--out", str(tmp_path / "c")])
    assert crowd.exit_code == 2


@pytest.mark.parametrize(("spec", "expected"), [("wide:cam1", ("cam1", 4)), ("wide:cam3:3", ("cam3", 3))])
def test_a_live_board_names_its_camera(spec: str, expected: tuple[str, int]) -> None:
    assert parse_wide(spec) == expected


@pytest.mark.parametrize("spec", ["wide", "wide:cam", "wide:2", "wide:cam5", "wide:cam3:2"])
def test_a_live_board_refuses_a_camera_the_layout_lacks(spec: str) -> None:
    with pytest.raises(SimulationError, match=r"sim:wide|no camera"):
        WideCameraSource(spec)


@pytest.mark.slow
def test_live_boards_render_the_same_world_at_the_same_wall_time() -> None:
    """Two processes started at different times agree on the world: its time is the wall clock."""
    now = [1_763_900_000.0]
    one = WideCameraSource("wide:cam1:2", realtime=True, wall_clock=lambda: now[0], sleep=lambda s: None)
    two = WideCameraSource("wide:cam2:2", realtime=True, wall_clock=lambda: now[0], sleep=lambda s: None)
    one.open()
    frame = one.read()
    now[0] += 7.3
    two.open()
    later = two.read()
    assert frame is not None and later is not None
    assert later.index - frame.index == pytest.approx(7.3 * 30, abs=2)
    assert one.truth_at(now[0]) == two.truth_at(now[0])
    # stamped by each board's (wrong) clock at its exposure instant
    t_exposed = later.index / 30.0 + two.cam.phase_s
    assert later.t_capture_s == pytest.approx(t_exposed + two.cam.clock_offset_s)


@pytest.mark.slow
def test_calibrate_check_across_boards_shows_the_seam_error_in_the_overlap(wide: Path, tmp_path: Path) -> None:
    args = []
    for cam in ("cam1", "cam2"):
        where = wide / cam
        cal = tmp_path / cam / "calibration.json"
        cal.parent.mkdir()
        invoke(
            "calibrate",
            "points",
            str(where / "points.csv"),
            "--out",
            str(cal),
            "--image",
            str(where / "background.png"),
        )
        args += [str(cal), str(where / "check.csv")]
    text = invoke("calibrate", "check", *args)
    assert "seam cam1/cam2:" in text
    doc = json.loads(invoke("calibrate", "check", *args, "--json"))
    assert [b["board"] for b in doc["boards"]] == ["cam1", "cam2"]
    (seam,) = doc["seams"]
    assert (seam["a"], seam["b"]) == ("cam1", "cam2")
    assert seam["n"] >= 10  # the overlap's shared check points
    # two independent surveys and two clicks per point: under a centimetre on average, never several
    assert 0.05 < seam["mean_cm"] < 1.2 and seam["max_cm"] < 3.0


@pytest.mark.slow
def test_calibrate_check_wants_a_check_file_for_every_calibration(wide: Path) -> None:
    result = CliRunner().invoke(
        main, ["calibrate", "check", str(wide / "cam1" / "camera.json"), str(wide / "cam1" / "check.csv"), "x.json"]
    )
    assert result.exit_code == 2 and "pairs of arguments" in result.output
