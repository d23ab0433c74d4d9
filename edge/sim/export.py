"""``edge-ips sim render``: a scenario rendered to files a person (or the tracker) can use.

Written into the output directory:

* ``video.mp4``: the frames at 30 fps (MPEG-4 Part 2, OpenCV's ``mp4v``: a lossy codec, like a webcam stream);
* ``truth.csv``: ``frame,id,x,y,theta,vx,vy``, one row per rover per frame: marker centre in world cm at marker
  height, heading in radians, world velocity in cm/s, at the frame's time (the middle of its exposure);
* ``visibility.csv``: ``frame,id,visible``: the fraction of each marker's area in view and not hidden;
* ``background.png``: the empty scene as the camera captures it (lossless), the paper's reference frame;
* ``camera.json``: the camera model that rendered the scene (:func:`edge.camera.save_camera`);
* ``points.csv``: the 34 surveyed calibration points (``u,v,x,y``) with 0.5 px RMS measuring noise
  (:func:`edge.sim.targets.survey_points`);
* with ``kit``: ``check.csv`` (+ ``check_targets.png``), ``targets.png`` (printed targets on the check and the
  survey points, for ``calibrate check|points --refine-on``), ``floor.png`` + ``markers.csv`` (ArUco on the floor),
  ``boards/`` (checkerboards, when the lens distorts): the rest of a calibration session;
* ``scenario.json``: scenario, seed, frames, rovers (id, marker colour as seen, reflectance) and effects.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.camera import save_camera
from edge.errors import SimulationError
from edge.sim.scenarios import SimSetup, build
from edge.sim.scene import Heading
from edge.sim.source import frame_truth
from edge.sim.targets import (
    aruco_floor_frame,
    check_points,
    checkerboard_views,
    survey_points,
    survey_target_frame,
    targets_apart,
    write_markers_csv,
)

TRUTH_COLUMNS = ("frame", "id", "x", "y", "theta", "vx", "vy")


@dataclass(frozen=True)
class RenderSummary:
    out_dir: Path
    frames: int
    written: tuple[str, ...]
    render_ms_mean: float


def render_to_directory(
    scenario: str,
    out_dir: Path,
    *,
    frames: int | None = None,
    seed: int = 0,
    rovers: int | None = None,
    heading: Heading = "plain",
    kit: bool = False,
    progress: Callable[[int], None] | None = None,
) -> RenderSummary:
    """Render ``scenario`` into ``out_dir`` (created if needed); ``progress(n)`` is told of every ``n`` frames done.
    ``kit``: also write the rest of a calibration session (:func:`write_calibration_kit`)."""
    setup = build(scenario, seed=seed, rovers=rovers, frames=frames, heading=heading)
    ensure_directory(out_dir)
    renderer = setup.renderer()
    world = setup.world()
    cam = setup.camera
    video_path = out_dir / "video.mp4"
    writer = cv2.VideoWriter(str(video_path), cv2.VideoWriter.fourcc(*"mp4v"), setup.fps, (cam.width_px, cam.height_px))
    if not writer.isOpened():
        raise SimulationError(f"{video_path}: cannot open an MPEG-4 video writer")
    render_s = 0.0
    try:
        with (
            (out_dir / "truth.csv").open("w", newline="") as truth_file,
            (out_dir / "visibility.csv").open("w", newline="") as vis_file,
        ):
            truth_csv = csv.writer(truth_file)
            vis_csv = csv.writer(vis_file)
            truth_csv.writerow(TRUTH_COLUMNS)
            vis_csv.writerow(("frame", "id", "visible"))
            for i in range(setup.frames):
                state = world.state_at(i / setup.fps)
                t0 = time.perf_counter()
                image = renderer.render(state, i)
                render_s += time.perf_counter() - t0
                writer.write(image)
                truth = frame_truth(state, i, renderer.visibility)
                for r in truth.rovers:
                    truth_csv.writerow(
                        (
                            i,
                            r.rover_id,
                            _fixed(r.x_cm, 4),
                            _fixed(r.y_cm, 4),
                            _fixed(r.theta_rad, 6),
                            _fixed(r.vx_cm_s, 4),
                            _fixed(r.vy_cm_s, 4),
                        )
                    )
                    vis_csv.writerow((i, r.rover_id, f"{r.visible:.4f}"))
                if progress is not None:
                    progress(1)
    except OSError as exc:
        raise SimulationError(f"{out_dir}: cannot write ({exc.strerror})") from exc
    finally:
        writer.release()
    written = ["video.mp4", "truth.csv", "visibility.csv"]
    _write_image(out_dir / "background.png", renderer.background(0))
    written.append("background.png")
    save_camera(cam, out_dir / "camera.json")
    written.append("camera.json")
    survey = survey_points(setup.camera, rng=setup.seed)  # as a person makes it: 34 points, 0.5 px clicks
    survey.write_csv(out_dir / "points.csv")
    written.append("points.csv")
    if kit:
        written += write_calibration_kit(setup, out_dir, survey.xy_world_cm)
    (out_dir / "scenario.json").write_text(json.dumps(describe(setup, renderer), indent=2) + "\n")
    written.append("scenario.json")
    return RenderSummary(out_dir, setup.frames, tuple(written), 1000.0 * render_s / setup.frames)


def _fixed(value: float, digits: int) -> str:
    """Fixed-point text without a negative zero."""
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def ensure_directory(out_dir: Path) -> None:
    """Create the output directory (and parents) or say why not."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SimulationError(f"{out_dir}: cannot create the output directory ({exc.strerror})") from exc


def describe(setup: SimSetup, renderer: object | None = None) -> dict[str, object]:
    """What a run was made of, for ``scenario.json``: enough to configure a tracker for it."""
    from edge.sim.render import Renderer

    r = renderer if isinstance(renderer, Renderer) else setup.renderer()
    return {
        "scenario": setup.scenario,
        "seed": setup.seed,
        "frames": setup.frames,
        "fps": setup.fps,
        "marker_height_cm": setup.scene.rovers[0].body_height_cm if setup.scene.rovers else None,
        "rovers": [
            {
                "id": look.rover_id,
                "color_bgr": list(r.nominal_marker_bgr(look.rover_id)),
                "marker_reflectance_bgr": list(look.marker_bgr),
                "heading": look.heading,
                "marker_cm": [look.marker_length_cm, look.marker_width_cm],
                "body_cm": [look.body_length_cm, look.body_width_cm, look.body_height_cm],
            }
            for look in setup.scene.rovers
        ],
        "effects": setup.effects.describe(),
    }


def _write_image(path: Path, image: NDArray[np.uint8]) -> None:
    if not cv2.imwrite(str(path), image):
        raise SimulationError(f"{path}: cannot write")


def write_calibration_kit(setup: SimSetup, out_dir: Path, survey_xy_cm: NDArray[np.float64]) -> list[str]:
    """The rest of a calibration session in this scene (``edge.sim.targets``): ``check.csv`` (20 independent
    check points) with ``check_targets.png`` (printed targets on them, for ``calibrate check --refine-on``),
    ``targets.png`` (a photo of printed targets on the survey points ``survey_xy_cm``, those of ``points.csv``),
    ``floor.png`` with ``markers.csv`` (ArUco markers laid on the floor) and, when the lens distorts,
    ``boards/board_NN.png`` (checkerboard photos for ``edge-ips calibrate intrinsics``)."""
    check = check_points(setup.camera, rng=setup.seed + 1)
    check.write_csv(out_dir / "check.csv")
    written = ["check.csv"]
    apart = check.xy_world_cm[targets_apart(check.xy_world_cm)]  # random points: two may be too close for two cards
    _write_image(out_dir / "check_targets.png", survey_target_frame(setup.camera, apart, rng=setup.seed + 5))
    _write_image(out_dir / "targets.png", survey_target_frame(setup.camera, survey_xy_cm, rng=setup.seed + 4))
    written += ["check_targets.png", "targets.png"]
    floor = aruco_floor_frame(setup.camera, rng=setup.seed + 2)
    _write_image(out_dir / "floor.png", floor.image)
    write_markers_csv(out_dir / "markers.csv", floor.markers)
    written += ["floor.png", "markers.csv"]
    if setup.camera.has_distortion:
        checkerboard_views(setup.camera, rng=setup.seed + 3).write(out_dir / "boards")
        written.append("boards/")
    return written
