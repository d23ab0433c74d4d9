"""``edge-ips sim render wide --cameras N``: the wide arena rendered to files, one directory per camera.

Written into the output directory:

* ``truth.csv``: ``frame,id,x,y,theta,vx,vy``, one world truth for every camera (the columns of
  :mod:`edge.sim.export`), frame ``i`` at ``i / fps`` on cam1's clock, the shared clock;
* ``wide.json``: the layout (each camera's region, exposure phase and clock error: the truth a fusion's clock
  estimates are checked against, never read by the fusion), the rovers and the seed;
* ``cam1`` ... ``camN``, each with ``video.mp4`` (frame ``i`` exposed at ``i / fps + phase``), ``visibility.csv``
  (``frame,id,visible``: the share of each marker in this camera's view), ``background.png``, ``camera.json``,
  ``points.csv`` (34 survey points in this camera's region, in the shared floor frame, their pixels measured with
  0.5 px RMS click noise, as ``edge-ips calibrate points`` takes them), ``targets.png`` (a photo of printed targets
  on those points, for ``calibrate points --refine-on``), ``check.csv`` (check points, the overlaps'
  shared with the neighbouring cameras, for ``edge-ips calibrate check`` across boards) and ``rovers.toml`` (each
  rover's marker colour as this camera sees it, for ``edge-ips track --config``).
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edge.calibration.points import write_points_csv
from edge.camera import MARKER_HEIGHT_CM, save_camera
from edge.errors import SimulationError
from edge.sim.export import TRUTH_COLUMNS, ensure_directory
from edge.sim.render import Renderer
from edge.sim.targets import survey_points, survey_target_frame
from edge.sim.wide import WideCamera, WideSetup, build_wide

CHECK_POINTS = 80  # over the whole arena
SEAM_POINTS = 12  # more in each overlap of two cameras
CLICK_NOISE_PX = 0.5  # RMS, as edge.sim.targets measures survey points


@dataclass(frozen=True)
class WideSummary:
    out_dir: Path
    frames: int
    cameras: tuple[str, ...]
    render_ms_mean: float


def render_wide_to_directory(
    out_dir: Path,
    *,
    cameras: int = 4,
    frames: int | None = None,
    seed: int = 0,
    rovers: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> WideSummary:
    """Render the wide arena seen by ``cameras`` boards into ``out_dir``; ``progress(n)`` after each frame."""
    setup = build_wide(cameras, seed=seed, rovers=rovers, frames=frames)
    ensure_directory(out_dir)
    world = setup.world()
    renderers = [setup.renderer(cam) for cam in setup.cameras]
    dirs = [out_dir / cam.name for cam in setup.cameras]
    writers = []
    for cam, where in zip(setup.cameras, dirs, strict=True):
        ensure_directory(where)
        writer = cv2.VideoWriter(
            str(where / "video.mp4"),
            cv2.VideoWriter.fourcc(*"mp4v"),
            setup.fps,
            (cam.camera.width_px, cam.camera.height_px),
        )
        if not writer.isOpened():
            raise SimulationError(f"{where / 'video.mp4'}: cannot open an MPEG-4 video writer")
        writers.append(writer)
    render_s = 0.0
    try:
        with (out_dir / "truth.csv").open("w", newline="") as truth_file:
            truth = csv.writer(truth_file)
            truth.writerow(TRUTH_COLUMNS)
            visibility = [(where / "visibility.csv").open("w", newline="") for where in dirs]
            try:
                vis = [csv.writer(f) for f in visibility]
                for w in vis:
                    w.writerow(("frame", "id", "visible"))
                for i in range(setup.frames):
                    for r in world.state_at(i / setup.fps).rovers:
                        truth.writerow(
                            (
                                i,
                                r.rover_id,
                                *(
                                    _fixed(v, d)
                                    for v, d in (
                                        (r.x_cm, 4),
                                        (r.y_cm, 4),
                                        (r.theta_rad, 6),
                                        (r.vx_cm_s, 4),
                                        (r.vy_cm_s, 4),
                                    )
                                ),
                            )
                        )
                    for cam, renderer, writer, w in zip(setup.cameras, renderers, writers, vis, strict=True):
                        state = world.state_at(i / setup.fps + cam.phase_s)
                        t0 = time.perf_counter()
                        writer.write(renderer.render(state, i))
                        render_s += time.perf_counter() - t0
                        for r in state.rovers:
                            w.writerow((i, r.rover_id, f"{renderer.visibility.get(r.rover_id, 0.0):.4f}"))
                    if progress is not None:
                        progress(1)
            finally:
                for f in visibility:
                    f.close()
    except OSError as exc:
        raise SimulationError(f"{out_dir}: cannot write ({exc.strerror})") from exc
    finally:
        for writer in writers:
            writer.release()
    for cam, renderer, where in zip(setup.cameras, renderers, dirs, strict=True):
        _write_camera_files(setup, cam, renderer, where)
    _write_check_points(setup, dirs)
    (out_dir / "wide.json").write_text(json.dumps(describe_wide(setup), indent=2) + "\n")
    count = setup.frames * len(setup.cameras)
    return WideSummary(out_dir, setup.frames, tuple(c.name for c in setup.cameras), 1000.0 * render_s / count)


def _fixed(value: float, digits: int) -> str:
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def _write_camera_files(setup: WideSetup, cam: WideCamera, renderer: Renderer, where: Path) -> None:
    if not cv2.imwrite(str(where / "background.png"), renderer.background(0)):
        raise SimulationError(f"{where / 'background.png'}: cannot write")
    save_camera(cam.camera, where / "camera.json")
    k = setup.cameras.index(cam)
    survey = survey_points(cam.camera, rng=setup.seed * 16 + k, area_cm=cam.region_cm)
    survey.write_csv(where / "points.csv")
    targets = survey_target_frame(cam.camera, survey.xy_world_cm, rng=setup.seed * 16 + k)
    if not cv2.imwrite(str(where / "targets.png"), targets):
        raise SimulationError(f"{where / 'targets.png'}: cannot write")
    lines = [f"# The rovers' marker colours as {cam.name} sees them (edge-ips track --config).", ""]
    for rover in setup.rover_configs(renderer):
        lines += ["[[rovers]]", f'id = "{rover.id}"', f"color_bgr = {list(rover.color_bgr)}", ""]
    (where / "rovers.toml").write_text("\n".join(lines))


def seam_check_points(setup: WideSetup) -> np.ndarray:
    """(N, 2) world cm: check points spread over the arena, plus more in every overlap of two regions."""
    rng = np.random.default_rng(np.random.SeedSequence([setup.seed, 0xC4EC]))
    x0, y0, x1, y1 = setup.arena_cm
    pts = [np.column_stack([rng.uniform(x0, x1, CHECK_POINTS), rng.uniform(y0, y1, CHECK_POINTS)])]
    regions = [c.region_cm for c in setup.cameras]
    for a in range(len(regions)):
        for b in range(a + 1, len(regions)):
            lo = np.maximum(regions[a][:2], regions[b][:2])
            hi = np.minimum(regions[a][2:], regions[b][2:])
            if np.all(hi > lo):
                pts.append(
                    np.column_stack([rng.uniform(lo[0], hi[0], SEAM_POINTS), rng.uniform(lo[1], hi[1], SEAM_POINTS)])
                )
    return np.round(np.concatenate(pts), 1)


def _write_check_points(setup: WideSetup, dirs: list[Path]) -> None:
    """Each camera's ``check.csv``: the check points in its region, measured in its image with click noise."""
    xy = seam_check_points(setup)
    for k, (cam, where) in enumerate(zip(setup.cameras, dirs, strict=True)):
        x0, y0, x1, y1 = cam.region_cm
        mine = xy[(xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)]
        gen = np.random.default_rng(setup.seed * 16 + k + 8)
        uv = cam.camera.project(np.column_stack([mine, np.full(len(mine), MARKER_HEIGHT_CM)]))
        uv += gen.normal(0.0, CLICK_NOISE_PX / math.sqrt(2.0), uv.shape)  # the survey's noise model
        write_points_csv(where / "check.csv", uv, mine)


def describe_wide(setup: WideSetup) -> dict[str, object]:
    """The layout, for ``wide.json``: enough to check a fusion against (phases and clocks are truth)."""
    return {
        "scenario": "wide",
        "seed": setup.seed,
        "frames": setup.frames,
        "fps": setup.fps,
        "arena_cm": list(setup.arena_cm),
        "cameras": [
            {
                "name": cam.name,
                "region_cm": [round(v, 2) for v in cam.region_cm],
                "phase_s": round(cam.phase_s, 6),
                "clock_offset_s": round(cam.clock_offset_s, 6),
                "position_cm": [round(float(v), 2) for v in cam.camera.position_cm],
            }
            for cam in setup.cameras
        ],
        "rovers": [
            {"id": look.rover_id, "marker_reflectance_bgr": list(look.marker_bgr)} for look in setup.scene.rovers
        ],
    }
