"""``edge-ips sim render`` and ``edge-ips sim scenarios``: files written, help with examples, one-line errors."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from edge.camera import load_camera
from edge.cli import main
from edge.sim.scenarios import SCENARIOS


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def test_scenarios_lists_each_with_one_line():
    result = run("sim", "scenarios")
    assert result.exit_code == 0
    lines = result.output.strip().splitlines()
    assert [line.split()[0] for line in lines] == list(SCENARIOS)


def test_scenarios_json_is_machine_readable():
    result = run("sim", "scenarios", "--json")
    rows = json.loads(result.output)
    assert {r["name"] for r in rows} == set(SCENARIOS)
    assert all(r["rovers"] >= 1 and r["frames"] >= 1 for r in rows)


@pytest.mark.parametrize("command", [["sim"], ["sim", "render"], ["sim", "scenarios"]])
def test_help_renders_with_an_example(command):
    result = run(*command, "--help")
    assert result.exit_code == 0
    assert "Example:" in result.output


@pytest.mark.slow
def test_render_writes_video_truth_background_and_camera(tmp_path):
    out = tmp_path / "run"
    result = run("sim", "render", "lab", "--out", str(out), "--frames", "6", "--seed", "2")
    assert result.exit_code == 0, result.output
    assert "wrote 6 frames of lab" in result.output
    with (out / "truth.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["frame", "id", "x", "y", "theta", "vx", "vy"]
    assert len(rows) == 1 + 6 * 3
    assert {r[1] for r in rows[1:]} == {"red", "green", "blue"}
    video = cv2.VideoCapture(str(out / "video.mp4"))
    assert video.get(cv2.CAP_PROP_FPS) == pytest.approx(30.0)
    frames = 0
    while True:
        ok, frame = video.read()
        if not ok:
            break
        assert frame.shape == (720, 1280, 3)
        frames += 1
    assert frames == 6
    background = cv2.imread(str(out / "background.png"))
    assert background.shape == (720, 1280, 3)
    camera = load_camera(out / "camera.json")
    assert (camera.width_px, camera.height_px) == (1280, 720)
    described = json.loads((out / "scenario.json").read_text())
    assert [r["id"] for r in described["rovers"]] == ["red", "green", "blue"]
    with (out / "visibility.csv").open() as f:
        vis = list(csv.reader(f))
    assert vis[0] == ["frame", "id", "visible"] and len(vis) == 1 + 18


@pytest.mark.slow
def test_render_truth_matches_the_scenario(tmp_path):
    out = tmp_path / "run"
    run("sim", "render", "crowd", "--out", str(out), "--frames", "2", "--rovers", "4", "--seed", "9")
    with (out / "truth.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 8
    from edge.sim.scenarios import build

    state = build("crowd", seed=9, rovers=4, frames=2).world().state_at(1 / 30)
    got = {r["id"]: (float(r["x"]), float(r["y"])) for r in rows if r["frame"] == "1"}
    for rover in state.rovers:
        assert got[rover.rover_id] == pytest.approx((rover.x_cm, rover.y_cm), abs=1e-4)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sim", "render", "moon", "--out", "{tmp}/x"], "unknown scenario 'moon'"),
        (
            ["sim", "render", "lab", "--out", "{tmp}/file.txt/run", "--frames", "1"],
            "cannot create the output directory",
        ),
    ],
)
def test_bad_requests_fail_with_one_line_and_exit_code_2(tmp_path, args, message):
    (tmp_path / "file.txt").write_text("not a directory")
    result = run(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert result.exit_code == 2
    assert message in result.output
    assert "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.parametrize("args", [["--frames", "0"], ["--rovers", "0"], ["--rovers", "65"], ["--seed", "x"]])
def test_bad_option_values_are_usage_errors(tmp_path, args):
    result = run("sim", "render", "lab", "--out", str(tmp_path / "x"), *args)
    assert result.exit_code == 2
    assert "Invalid value" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["lab", "--rovers", "49"], "--rovers 49: at most 48 in scenario lab (64 in wide)"),
        (["lab", "--cameras", "2"], "--cameras is for the wide scenario, not lab"),
        (["wide", "--rovers", "65"], "Invalid value"),
    ],
)
def test_rover_and_camera_counts_are_checked_per_scenario(tmp_path, args, message):
    result = run("sim", "render", args[0], "--out", str(tmp_path / "x"), *args[1:])
    assert result.exit_code == 2
    assert message in result.output
    assert not (tmp_path / "x").exists()  # checked before anything is written


@pytest.mark.slow
def test_background_is_the_empty_scene(tmp_path):
    out = tmp_path / "run"
    run("sim", "render", "lab", "--out", str(out), "--frames", "1")
    background = cv2.imread(str(out / "background.png")).astype(int)
    video = cv2.VideoCapture(str(out / "video.mp4"))
    ok, frame = video.read()
    assert ok
    diff = np.abs(frame.astype(int) - background).max(axis=2)
    # the rovers are the only large differences (the rest is noise and video compression)
    assert (diff > 60).mean() < 0.01
    assert (diff > 60).sum() > 200
