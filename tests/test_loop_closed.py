"""The closed loop end to end: rendered frames -> Pipeline -> MqttPublisher -> a real broker -> the rovers' firmware
(HostRover) -> wheel commands -> the simulated world. The short version of the formation bars (the full one, 20 seeds
per formation, is benchmarks/bench_formation.py), and the safety bar: camera feed stopped or broker killed mid-run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from edge.cli import main
from edge.messages import parse_pose
from edge.sim.loop import LoopConfig, LoopRecord, run
from edge.sim.metrics import Bar, converged_frame, formation_error
from edge.sim.report import formation_errors, safety, summarize
from tests.support.mosquitto import Mosquitto


def assert_safe_stop(record: LoopRecord) -> None:
    """Every rover was driving when the poses stopped, and within 0.5 s of its last fresh own pose its motors were
    cut for good (simulated clock, the recorded duties) and its body was at rest (the simulated world)."""
    s = safety(record)
    assert s is not None
    for rid, r in s["rovers"].items():
        assert r["last_fresh_pose_ms"] <= s["event_ms"] + record.config.latency_ms + 40, rid
        assert r["driving_when_stopped"], f"{rid} was not driving when the poses stopped: the test proves nothing"
        assert r["motors_off_after_ms"] is not None, f"{rid} never stopped"
        assert r["motors_off_after_ms"] <= 500, f"{rid} stopped {r['motors_off_after_ms']} ms after its last pose"
        assert r["at_rest_after_ms"] <= 500, f"{rid} came to rest {r['at_rest_after_ms']:.0f} ms after its last pose"
    log = record.motors[record.ids[0]]
    assert log.halt[-1] in ("stale", "disconnected")


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "seed"), [("line", 11), ("rendezvous", 12), ("triangle", 13)])
def test_formation_converges_within_240_frames_without_touching(kind: str, seed: int) -> None:
    record = run(LoopConfig(kind, seed=seed, frames=300))
    errors = formation_errors(record)
    conv = converged_frame(errors)
    assert conv is not None and conv <= Bar(kind).within_frames, f"bar error at the end {errors[-1]:.2f}"
    m = summarize(record)
    assert m["min_body_gap_cm"] > 0.0
    assert m["min_centre_distance_cm"] >= 2 * m["rover"]["body_radius_cm"]
    assert m["ips_error_cm"]["max"] < 5.0
    # the starts are the issue's: 1.5 m apart
    start = record.truth[0, :, :2]
    assert min(np.hypot(*(start[i] - start[j])) for i in range(3) for j in range(i + 1, 3)) >= 150.0
    # every pose the rovers got is one the tracker made of a rendered frame, in order
    frames = {rid: [f for f, r, _ in record.published if r == rid] for rid in record.ids}
    assert all(f == sorted(f) and len(f) >= 0.95 * 300 for f in frames.values())


@pytest.mark.slow
def test_formation_through_mosquitto(tmp_path: Path) -> None:
    with Mosquitto(tmp_path / "mosquitto") as broker:
        record = run(LoopConfig("triangle", seed=21, frames=240, broker_url=broker.url))
    assert formation_error(Bar("triangle"), record.truth[-1, :, :2]) <= 0.0
    assert sum(record.deliveries_late.values()) < 0.05 * 3 * 240


@pytest.mark.slow
def test_rovers_stop_when_the_camera_feed_stops() -> None:
    record = run(LoopConfig("line", seed=31, frames=90, feed_stop_frame=45))
    assert record.frames_tracked == 45
    assert_safe_stop(record)
    # and they stay stopped: the bodies are at rest at the end
    assert np.hypot(*(record.truth[-1, :, :2] - record.truth[-5, :, :2]).T).max() < 0.01


@pytest.mark.slow
def test_rovers_stop_when_the_embedded_broker_dies() -> None:
    record = run(LoopConfig("rendezvous", seed=32, frames=90, broker_stop_frame=45))
    assert record.poses_dropped > 0  # the publisher drops, never queues, while disconnected
    assert_safe_stop(record)


@pytest.mark.slow
def test_rovers_stop_when_mosquitto_dies(tmp_path: Path) -> None:
    with Mosquitto(tmp_path / "mosquitto") as broker:

        def kill(k: int) -> None:
            if k == 45:
                broker.stop()

        record = run(
            LoopConfig("triangle", seed=33, frames=90, broker_url=broker.url, broker_stop_frame=45), on_frame=kill
        )
    assert_safe_stop(record)


@pytest.mark.slow
def test_sim_formation_writes_what_recomputes_its_metrics(tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = CliRunner().invoke(
        main, ["sim", "formation", "triangle", "--seed", "41", "--frames", "60", "--out", str(out)]
    )
    assert result.exit_code == 1, result.output  # 60 frames (2 s) is too short to form: written, then exit 1
    for name in ("metrics.json", "truth.csv", "poses.jsonl", "motors.csv", "map.png", "snapshots.png", "xy_time.png"):
        assert (out / name).stat().st_size > 0, name
    metrics = json.loads((out / "metrics.json").read_text())
    rows = (out / "truth.csv").read_text().splitlines()
    assert rows[0] == "frame,id,x,y,theta" and len(rows) == 1 + 60 * 3
    last = np.array([[float(v) for v in r.split(",")[2:4]] for r in rows[-3:]])
    assert formation_error(Bar("triangle"), last) == pytest.approx(metrics["final_beyond_bar_cm"], abs=0.01)
    poses = [parse_pose(line) for line in (out / "poses.jsonl").read_bytes().splitlines()]
    assert len(poses) == metrics["messages"]["poses_published"] > 0
    truth = {(int(r.split(",")[0]), r.split(",")[1]): r.split(",") for r in rows[1:]}
    worst = max(abs(p.x - float(truth[(p.frame, p.id)][2])) for p in poses)
    assert worst == pytest.approx(metrics["ips_error_cm"]["max"], abs=metrics["ips_error_cm"]["max"]) and worst < 5
    assert "converged at frame" in result.output or "FAILS" in result.output


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["circle", "diagonal"])
def test_sim_trajectory_tracks_a_scripted_path(tmp_path: Path, kind: str) -> None:
    out = tmp_path / kind
    args = ["sim", "trajectory", kind, "--frames", "90", "--out", str(out), "--json"]
    result = CliRunner().invoke(main, [*args, *(["--video"] if kind == "diagonal" else [])])
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.output[result.output.index("{") :])
    assert metrics["ips_error_cm"]["n"] >= 0.95 * 90 * 3
    assert metrics["ips_error_cm"]["p95"] < 2.0
    assert (out / "xy_time.png").stat().st_size > 0
    if kind == "diagonal":  # the annotated camera view: every frame, readable
        import cv2

        video = cv2.VideoCapture(str(out / "camera.mp4"))
        assert video.isOpened() and int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 90
        ok, image = video.read()
        video.release()
        assert ok and image.shape[:2] == (720, 1280)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["formation", "triangle", "--rovers", "2"], "triangle needs at least 3 rovers"),
        (["formation", "line", "--broker", "tcp://x"], "--broker"),
    ],
)
def test_bad_experiment_options_are_one_line_errors(tmp_path: Path, args: list[str], message: str) -> None:
    result = CliRunner().invoke(main, ["sim", *args, "--out", str(tmp_path / "x")])
    assert result.exit_code == 2
    assert message in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "x").exists()  # refused before anything was written


def test_an_output_directory_that_cannot_be_made_is_a_one_line_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a directory")
    result = CliRunner().invoke(main, ["sim", "formation", "line", "--frames", "2", "--out", str(tmp_path / "file/x")])
    assert result.exit_code == 2
    assert "cannot create the output directory" in result.output and "Traceback" not in result.output


@pytest.mark.slow
def test_a_run_that_misses_its_bar_exits_1_and_still_writes_everything(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["sim", "formation", "line", "--frames", "3", "--out", str(tmp_path / "r")])
    assert result.exit_code == 1, result.output
    assert "FAILS" in result.output
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["passed"]["within_frames"] is False


@pytest.mark.slow
def test_more_rovers_than_fit_150_cm_apart_start_100_cm_apart() -> None:
    record = run(LoopConfig("rendezvous", rovers=12, seed=0, frames=1))
    xy = record.truth[0, :, :2]
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    assert len(xy) == 12 and d[~np.eye(12, dtype=bool)].min() >= 100.0
