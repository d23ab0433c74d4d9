"""``edge-ips track`` and ``edge-ips plot`` end to end on a short rendered video, and their bad inputs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from edge.camera import paper_camera, save_camera
from edge.centre_offsets import InlineFits
from edge.cli import main
from edge.messages import dumps, parse_pose
from edge.offline import open_track_job
from edge.pooled_fits import PooledFits
from edge.tracker_config import TrackerConfig
from tests.support.track import COLORS, SynthRover, shared_scene

FRAMES = 24


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 24-frame mp4 of three rovers, the camera it was seen by, the empty scene, and the ground truth."""
    out = tmp_path_factory.mktemp("clip")
    scene = shared_scene()
    save_camera(scene.camera, out / "camera.json")
    cv2.imwrite(str(out / "background.png"), scene.floor)
    writer = cv2.VideoWriter(str(out / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (1280, 720))
    rng = np.random.default_rng(0)
    truth = {}
    for i in range(FRAMES):
        t = i / 30.0
        rovers = [
            SynthRover("red", 150.0 + 20.0 * t, 200.0, 0.0, COLORS["red"]),
            SynthRover("green", 260.0, 380.0 - 15.0 * t, -math.pi / 2, COLORS["green"]),
            SynthRover("blue", 80.0, 90.0, 0.4, COLORS["blue"], visible=i < 16),  # leaves (is hidden) at frame 16
        ]
        truth.update({(i, r.id): (r.x, r.y) for r in rovers})
        writer.write(scene.render(rovers, noise_sigma=2.0, rng=rng))
    writer.release()
    (out / "truth.json").write_text(json.dumps({f"{k[0]}:{k[1]}": v for k, v in truth.items()}))
    return out


def invoke(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


@pytest.mark.slow
def test_track_writes_one_pose_per_rover_per_frame_exactly_as_published(clip: Path, tmp_path: Path):
    out = tmp_path / "poses.jsonl"
    result = invoke("track", str(clip / "video.mp4"), "--calibration", str(clip / "camera.json"), "--out", str(out))
    assert result.exit_code == 0, result.output
    lines = out.read_bytes().splitlines()
    poses = [parse_pose(line) for line in lines]
    assert all(dumps(p) == line for p, line in zip(poses, lines, strict=True))  # canonical bytes
    counts = {rid: sum(p.id == rid for p in poses) for rid in ("red", "green", "blue")}
    assert counts == {"red": FRAMES, "green": FRAMES, "blue": 16}
    assert [p.seq for p in poses if p.id == "red"] == list(range(FRAMES))
    truth = {tuple(k.split(":")): v for k, v in json.loads((clip / "truth.json").read_text()).items()}
    errors = [math.hypot(p.x - truth[(str(p.frame), p.id)][0], p.y - truth[(str(p.frame), p.id)][1]) for p in poses]
    assert np.mean(errors) < 0.3
    assert poses[-1].t == pytest.approx((FRAMES - 1) / 30.0, abs=1e-3)
    assert "frames/s processing" in result.output
    assert "detection 88.9%" in result.output  # blue hidden for 8 of 24 frames
    assert "blue: 16 poses" in result.output


@pytest.mark.slow
def test_track_writes_the_same_bytes_with_the_fits_pooled_as_with_them_in_the_loop(
    clip: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """``track`` runs the edge fits in worker processes on the in-loop schedule: its poses are those of the fits run
    in the frame loop, byte for byte, and the fits did move them (they are not the poses without the fits)."""
    outputs = {}
    for name in ("pooled", "inline", "off"):
        if name == "inline":
            monkeypatch.setattr("edge.offline.PooledFits", InlineFits)
        config = TrackerConfig(edge_offsets=name != "off")
        job = open_track_job(clip / "video.mp4", clip / "camera.json", config)
        fits = job.tracker.offsets.fits if job.tracker.offsets is not None else None  # type: ignore[attr-defined]
        assert type(fits) is {"pooled": PooledFits, "inline": InlineFits, "off": type(None)}[name]
        job.run(tmp_path / f"{name}.jsonl")
        if fits is not None:
            assert sum(job.tracker.offsets.samples(i) for i in range(3)) > 0  # type: ignore[attr-defined]
        if isinstance(fits, PooledFits):
            assert not fits.inline and fits.worker_pids() == []  # the pool served, and was stopped by the run
        outputs[name] = (tmp_path / f"{name}.jsonl").read_bytes()
    assert outputs["pooled"] == outputs["inline"]
    assert outputs["pooled"] != outputs["off"]


@pytest.mark.slow
@pytest.mark.parametrize("method", ["centroid", "meanshift", "paper"])
def test_track_runs_every_method_and_prints_a_json_summary(clip: Path, tmp_path: Path, method: str):
    out = tmp_path / "poses.jsonl"
    args = ["track", str(clip / "video.mp4"), "--calibration", str(clip / "camera.json"), "--out", str(out)]
    result = invoke(*args, "--method", method, "--background", str(clip / "background.png"), "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output.strip().splitlines()[-1])
    assert summary["frames"] == FRAMES
    assert summary["per_rover"]["red"] == FRAMES
    assert summary["processing_fps"] > 0


@pytest.mark.slow
def test_track_reads_rovers_and_method_from_a_config_file(clip: Path, tmp_path: Path):
    config = tmp_path / "rovers.toml"
    config.write_text('method = "centroid"\n[[rovers]]\nid = "red"\ncolor_bgr = [50, 45, 190]\n')
    out = tmp_path / "poses.jsonl"
    args = ["track", str(clip / "video.mp4"), "--calibration", str(clip / "camera.json"), "--out", str(out)]
    result = invoke(*args, "--config", str(config))
    assert result.exit_code == 0, result.output
    assert {parse_pose(line).id for line in out.read_bytes().splitlines()} == {"red"}


def _one_line_error(result, *fragments: str) -> None:
    assert result.exit_code == 2, result.output
    text = result.output.strip()
    assert len(text.splitlines()) == 1, text
    assert text.startswith("Error:")
    assert "Traceback" not in text
    for fragment in fragments:
        assert fragment in text, text


@pytest.mark.parametrize(
    ("make_video", "fragment"),
    [
        (lambda d: d / "missing.mp4", "no such video file"),
        (lambda d: (d / "notes.mp4").write_text("not a video") and d / "notes.mp4", "cannot"),
        (lambda d: (d / "empty.mp4").write_bytes(b"") or d / "empty.mp4", "cannot"),
    ],
)
def test_an_unreadable_video_is_a_one_line_error(clip: Path, tmp_path: Path, make_video, fragment):
    video = make_video(tmp_path)
    out = tmp_path / "poses.jsonl"
    result = invoke("track", str(video), "--calibration", str(clip / "camera.json"), "--out", str(out))
    _one_line_error(result, str(video), fragment)


def test_a_calibration_for_another_image_size_is_a_one_line_error(clip: Path, tmp_path: Path):
    other = tmp_path / "camera-640.json"
    cam = paper_camera()
    from edge.camera import PinholeCamera

    k = cam.camera_matrix.copy()
    k[:2] /= 2.0
    save_camera(PinholeCamera(k, cam.dist_coeffs, cam.rvec, cam.tvec, 640, 360), other)
    out = tmp_path / "poses.jsonl"
    result = invoke("track", str(clip / "video.mp4"), "--calibration", str(other), "--out", str(out))
    _one_line_error(result, str(other), "640x360", "1280x720")


@pytest.mark.parametrize(
    ("content", "fragment"),
    [(None, "cannot read"), ("{not json", "malformed JSON"), ('{"kind": "edge-ips/camera"}', "invalid camera file")],
)
def test_a_bad_calibration_file_is_a_one_line_error(clip: Path, tmp_path: Path, content, fragment):
    path = tmp_path / "calibration.json"
    if content is not None:
        path.write_text(content)
    out = tmp_path / "poses.jsonl"
    result = invoke("track", str(clip / "video.mp4"), "--calibration", str(path), "--out", str(out))
    _one_line_error(result, str(path), fragment)


def test_a_background_of_another_size_is_a_one_line_error(clip: Path, tmp_path: Path):
    small = tmp_path / "bg.png"
    cv2.imwrite(str(small), np.zeros((10, 20, 3), np.uint8))
    args = ["track", str(clip / "video.mp4"), "--calibration", str(clip / "camera.json")]
    result = invoke(*args, "--out", str(tmp_path / "p.jsonl"), "--background", str(small))
    _one_line_error(result, str(small), "20x10")


def test_a_bad_config_file_is_a_one_line_error(clip: Path, tmp_path: Path):
    config = tmp_path / "rovers.toml"
    config.write_text("[[rovers]]\nid = 'red'\ncolor_bgr = 'red'\n")
    args = ["track", str(clip / "video.mp4"), "--calibration", str(clip / "camera.json")]
    result = invoke(*args, "--out", str(tmp_path / "p.jsonl"), "--config", str(config))
    _one_line_error(result, str(config), "rovers.0.color_bgr")


@pytest.mark.slow
def test_plot_draws_the_trajectories(clip: Path, tmp_path: Path):
    poses = tmp_path / "poses.jsonl"
    invoke("track", str(clip / "video.mp4"), "--calibration", str(clip / "camera.json"), "--out", str(poses))
    png = tmp_path / "plot.png"
    result = invoke("plot", str(poses), "--out", str(png), "--title", "lab")
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(png))
    assert image is not None and image.shape[0] > 400
    assert "red: 24" in result.output


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b'{"v":1,"id":"red"}\n', "line 1"),
        (b"", "no poses"),
        (b"\xff\xfe\n", "line 1"),
    ],
)
def test_plot_of_a_bad_poses_file_is_a_one_line_error(tmp_path: Path, content: bytes, fragment: str):
    poses = tmp_path / "poses.jsonl"
    poses.write_bytes(content)
    result = invoke("plot", str(poses), "--out", str(tmp_path / "plot.png"))
    _one_line_error(result, str(poses), fragment)


def test_every_new_command_has_help_with_an_example():
    for command in ("track", "plot"):
        result = invoke(command, "--help")
        assert result.exit_code == 0
        assert "Example:" in result.output


def test_track_uses_a_calibration_file_made_by_edge_ips_calibrate(clip: Path, tmp_path: Path):
    from edge.calibration import Calibration, save_calibration
    from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM

    cam = shared_scene().camera
    cal = Calibration(
        cam.plane_homography(MARKER_HEIGHT_CM), 1280, 720, MARKER_HEIGHT_CM, (0.0, 0.0, AREA_WIDTH_CM, AREA_LENGTH_CM)
    )
    path = tmp_path / "calibration.json"
    save_calibration(cal, path)
    out = tmp_path / "poses.jsonl"
    result = invoke("track", str(clip / "video.mp4"), "--calibration", str(path), "--out", str(out))
    assert result.exit_code == 0, result.output
    truth = {tuple(k.split(":")): v for k, v in json.loads((clip / "truth.json").read_text()).items()}
    poses = [parse_pose(line) for line in out.read_bytes().splitlines()]
    errors = [math.hypot(p.x - truth[(str(p.frame), p.id)][0], p.y - truth[(str(p.frame), p.id)][1]) for p in poses]
    assert np.mean(errors) < 0.3
