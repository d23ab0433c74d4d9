"""Tracking benchmarks (issue 5, "Measured"): Table IV stage times, scaling with rover count, Table V accuracy.

    python benchmarks/bench_tracking.py stages   [--frames N] [--seed S]
    python benchmarks/bench_tracking.py scale    [--frames N] [--counts 1,3,8,16,32]
    python benchmarks/bench_tracking.py accuracy [--scenarios lab,...] [--methods ...] [--seeds 0,1] [--frames N]
                                                 [--calibration camera|points] [--heading plain|two_tone]
    python benchmarks/bench_tracking.py all

Frames come from the simulator (``edge.sim``) rendered in memory first, so only the tracker is timed. Timing runs on
one core: ``cv2.setNumThreads(1)`` and single-threaded BLAS (set before numpy is imported). Frames are stamped with
the scenario's clock (index / fps), as a camera would stamp them at capture.

Accuracy, per scenario and tracker, against the simulator's ground truth (marker centre in world cm at 13 cm):

* error: distance of every reported pose from the true marker centre (cm): mean, 95th percentile, max;
* detection: share of rover-frames with the marker fully in view and unhidden (visible >= 0.99) that got a pose
  (also given for visible >= 0.5);
* swaps: poses nearer another rover's true centre than their own and more than 5 cm off;
* heading: median |error| over rover-frames of rovers moving faster than 2 cm/s that got a heading, and the
  share of those frames that had one;
* ms/frame: median processing time per frame.

``paper`` is the straightforward full-frame pipeline of the paper (edge/trackers/paper.py), run in the same loop on
the same frames with the scenario's empty-scene reference, so speed-up and accuracy gain are ratios of one run.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

if importlib.util.find_spec("edge") is None:  # run from a checkout without the package installed
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.tracker_config import TrackerConfig  # noqa: E402
from edge.trackers.base import CameraPlaneMapping  # noqa: E402
from edge.trackers.factory import build_tracker  # noqa: E402
from edge.tracking import Frame  # noqa: E402

SCENARIOS = ("lab", "drift", "sun", "cross", "occlusion", "lens", "crowd")
METHODS = ("centroid", "particles", "meanshift", "paper")
# Table IV rows (the paper's names) and the pipeline stages that implement them.
TABLE_IV = (
    ("Reference frame (background refresh)", ("reference",)),
    ("Image subtraction (eq. 2)", ("subtraction",)),
    ("RGB colour planes extraction", ("planes",)),
    ("Image calibration (pixel -> world)", ("calibration",)),
    ("Thresholding (automatic interval)", ("threshold",)),
    ("P.M.O. - erosion", ("erosion",)),
    ("A.M.O. - automatic hole filling", ("holes",)),
    ("Tracker (particles, centre of mass)", ("measure",)),
    ("Search windows", ("window",)),
    ("Reacquisition pass (1/4 resolution)", ("acquire",)),
    ("Filter, identity, heading", ("filter",)),
)
PAPER_TABLE_IV_MS = {
    "Reference frame (background refresh)": 51.4,
    "Image subtraction (eq. 2)": 1.1,
    "RGB colour planes extraction": 2.7,
    "Image calibration (pixel -> world)": 91.2,
    "Thresholding (automatic interval)": 0.1,
    "P.M.O. - erosion": 2.9,
    "A.M.O. - automatic hole filling": 3.3,
}


@dataclass
class Clip:
    """Rendered frames of one scenario run with their ground truth."""

    name: str
    seed: int
    fps: float
    frames: list[np.ndarray]
    truth: list[dict[str, tuple[float, float, float, float, float, float]]]  # id -> x, y, theta, vx, vy, visible
    rovers: tuple
    camera: object
    background: np.ndarray


def render_clip(
    name: str, seed: int, frames: int | None = None, rovers: int | None = None, heading: str = "plain"
) -> Clip:
    from edge.sim.source import SimSource

    source = SimSource(name, seed=seed, realtime=False, rovers=rovers, frames=frames, heading=heading)  # type: ignore[arg-type]
    source.open()
    n = frames or source.setup.frames
    images, truth = [], []
    for _ in range(n):
        f = source.read()
        if f is None:
            break
        images.append(f.image)
        t = source.truth(f.index)
        truth.append({r.rover_id: (r.x_cm, r.y_cm, r.theta_rad, r.vx_cm_s, r.vy_cm_s, r.visible) for r in t.rovers})
    renderer = source.setup.renderer()
    background = renderer.background(0)
    configs = source.rover_configs()
    if heading == "two_tone":
        configs = tuple(c.model_copy(update={"front_color_bgr": front_color(renderer, c.id)}) for c in configs)
    source.close()
    return Clip(name, seed, source.setup.fps, images, truth, configs, source.setup.camera, background)


def front_color(renderer: object, rover_id: str) -> tuple[int, int, int]:
    """A two-tone marker's front colour as the camera sees it, the way the simulator's ``nominal_marker_bgr``
    computes the main colour (the benchmark reads the renderer's look and light, as an installer would measure
    the colour from a frame)."""
    look = renderer._look(rover_id)  # type: ignore[attr-defined]
    cam = renderer.camera  # type: ignore[attr-defined]
    centre = cam.project(np.array([[195.75, 274.75, look.body_height_cm]]))[0]
    u, v = round(float(centre[0])), round(float(centre[1]))
    lin = np.asarray(look.secondary_bgr) * float(renderer._backdrop.illumination[v, u])  # type: ignore[attr-defined]
    enc = np.clip(lin, 0.0, 1.0) ** (1.0 / renderer._gamma) * 255.0  # type: ignore[attr-defined]
    b, g, r = (round(float(c)) for c in enc)
    return b, g, r


def frame_of(image: np.ndarray, index: int, fps: float) -> Frame:
    t = index / fps
    return Frame(image=image, index=index, t_capture_s=t, t_mono_s=t)


@dataclass
class Score:
    errors: list[float] = field(default_factory=list)
    visible: int = 0
    detected: int = 0
    visible_half: int = 0
    detected_half: int = 0
    swaps: int = 0
    heading_errors: list[float] = field(default_factory=list)
    heading_errors_still: list[float] = field(default_factory=list)
    still: int = 0
    moving: int = 0
    ms: list[float] = field(default_factory=list)
    stages: list[dict[str, float]] = field(default_factory=list)  # per frame: stage -> ms (absent: did not run)

    def add(self, other: Score) -> None:
        self.errors += other.errors
        self.visible += other.visible
        self.detected += other.detected
        self.visible_half += other.visible_half
        self.detected_half += other.detected_half
        self.swaps += other.swaps
        self.heading_errors += other.heading_errors
        self.heading_errors_still += other.heading_errors_still
        self.still += other.still
        self.moving += other.moving
        self.ms += other.ms
        self.stages += other.stages

    def row(self) -> dict[str, float]:
        e = np.asarray(self.errors) if self.errors else np.array([math.nan])
        h = np.asarray(self.heading_errors) if self.heading_errors else np.array([math.nan])
        return {
            "mean": float(e.mean()),
            "p95": float(np.percentile(e, 95)),
            "max": float(e.max()),
            "det": self.detected / self.visible if self.visible else math.nan,
            "det50": self.detected_half / self.visible_half if self.visible_half else math.nan,
            "swaps": float(self.swaps),
            "head": float(np.median(h)),
            "head_cov": len(self.heading_errors) / self.moving if self.moving else math.nan,
            "head_still": float(np.median(self.heading_errors_still)) if self.heading_errors_still else math.nan,
            "head_still_cov": len(self.heading_errors_still) / self.still if self.still else math.nan,
            "ms": float(np.median(self.ms)) if self.ms else math.nan,
        }


def plane_mapping(clip: Clip, calibration: str) -> object:
    """``camera``: the scene camera itself (the tracker's error alone). ``points``: a calibration fitted with
    ``edge.calibration`` to 34 surveyed points with 0.5 px measuring noise (the whole system's error), with the
    lens intrinsics given when the camera has distortion (as ``edge-ips calibrate intrinsics`` would provide)."""
    if calibration == "camera":
        return CameraPlaneMapping(clip.camera)  # type: ignore[arg-type]
    from edge.calibration import Intrinsics, calibrate_points
    from edge.calibration.points import point_table
    from edge.sim.targets import survey_points

    cam = clip.camera
    survey = survey_points(cam, rng=1000 + clip.seed)  # type: ignore[arg-type]
    intrinsics = (
        Intrinsics(cam.camera_matrix, cam.dist_coeffs, cam.width_px, cam.height_px)  # type: ignore[attr-defined]
        if cam.has_distortion  # type: ignore[attr-defined]
        else None
    )
    table = point_table(survey.uv_px, survey.xy_world_cm)
    return calibrate_points(table, (1280, 720), intrinsics=intrinsics).calibration


def run_clip(clip: Clip, method: str, use_background: bool | None = None, calibration: str = "camera") -> Score:
    config = TrackerConfig(rovers=clip.rovers, method=method, fps=clip.fps)
    mapping = plane_mapping(clip, calibration)
    with_bg = (method == "paper") if use_background is None else use_background
    tracker = build_tracker(config, mapping, clip.background if with_bg else None)  # type: ignore[arg-type]
    score = Score()
    for i, image in enumerate(clip.frames):
        t0 = time.perf_counter()
        result = tracker.process(frame_of(image, i, clip.fps))
        score.ms.append((time.perf_counter() - t0) * 1e3)
        score.stages.append(dict(result.stage_ms))
        truth = clip.truth[i]
        got = {e.rover_id: e for e in result.estimates}
        for rid, (x, y, th, vx, vy, vis) in truth.items():
            if vis >= 0.99:
                score.visible += 1
                score.detected += rid in got
            if vis >= 0.5:
                score.visible_half += 1
                score.detected_half += rid in got
            e = got.get(rid)
            if e is None:
                continue
            err = math.hypot(e.x_cm - x, e.y_cm - y)
            score.errors.append(err)
            others = [math.hypot(e.x_cm - o[0], e.y_cm - o[1]) for oid, o in truth.items() if oid != rid]
            if err > 5.0 and others and min(others) < err:
                score.swaps += 1
            heading_error = (
                None if e.theta_rad is None else abs(math.degrees(math.remainder(e.theta_rad - th, math.tau)))
            )
            if math.hypot(vx, vy) > 2.0:
                score.moving += 1
                if heading_error is not None:
                    score.heading_errors.append(heading_error)
            else:
                score.still += 1
                if heading_error is not None:
                    score.heading_errors_still.append(heading_error)
    return score


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, OpenCV {cv2.__version__}"


# -- stages (Table IV) --------------------------------------------------------------------------------------------
def bench_stages(frames: int, seed: int) -> None:
    clip = render_clip("lab", seed, frames)
    score = run_clip(clip, "particles", use_background=False)
    paper = run_clip(clip, "paper")
    print(f"## Table IV: stage times, 1280x720, 3 rovers, one core ({machine()})")
    print(f"lab scenario seed {seed}, {len(clip.frames)} frames; median (and 95th percentile) ms per frame\n")
    print("| stage (paper's Table IV row) | windowed pipeline | full-frame paper pipeline | paper (Table IV) |")
    print("|---|---|---|---|")

    def per_frame(s: Score, keys: tuple[str, ...]) -> np.ndarray:
        return np.array([sum(frame.get(k, 0.0) for k in keys) for frame in s.stages])

    for name, keys in TABLE_IV:
        ours = per_frame(score, keys)
        theirs = per_frame(paper, keys)
        ref = PAPER_TABLE_IV_MS.get(name)
        print(
            f"| {name} | {np.median(ours):.3f} ({np.percentile(ours, 95):.3f}) | "
            f"{np.median(theirs):.3f} | {'' if ref is None else f'{ref:.1f}'} |"
        )
    acquire = [frame["acquire"] for frame in score.stages if "acquire" in frame]
    print(
        f"| **total after decode** | **{np.median(score.ms):.2f}** ({np.percentile(score.ms, 95):.2f}) | "
        f"**{np.median(paper.ms):.2f}** | ~10 (rows after acquisition) |"
    )
    print(f"\nreacquisition pass ran in {len(acquire)} of {len(score.ms)} frames", end="")
    if acquire:
        print(f" (median {np.median(acquire):.2f} ms when it ran)")
    else:
        print()
    print(f"speed-up over the full-frame paper pipeline: {np.median(paper.ms) / np.median(score.ms):.1f}x")


# -- scaling -----------------------------------------------------------------------------------------------------
def bench_scale(frames: int, counts: list[int], seed: int) -> None:
    print(f"## Time per frame against rover count, 1280x720, one core ({machine()})")
    print(f"crowd scenario (rovers circling), seed {seed}, {frames} frames each; particles tracker\n")
    print("| rovers | median ms/frame | p95 ms/frame | frames/s (median) | detection |")
    print("|---|---|---|---|---|")
    for n in counts:
        clip = render_clip("crowd", seed, frames, rovers=n)
        score = run_clip(clip, "particles", use_background=False)
        steady = np.asarray(score.ms[5:])
        row = score.row()
        print(
            f"| {n} | {np.median(steady):.2f} | {np.percentile(steady, 95):.2f} | {1000.0 / np.median(steady):.0f} | "
            f"{100.0 * row['det']:.2f}% |"
        )


# -- accuracy (Table V) ------------------------------------------------------------------------------------------
def bench_accuracy(
    scenarios: list[str], methods: list[str], seeds: list[int], frames: int | None, calibration: str, heading: str
) -> None:
    print(f"## Table V with numbers: accuracy per scenario and tracker ({machine()})")
    print(
        f"seeds {','.join(map(str, seeds))}; {'all' if frames is None else frames} frames per run; "
        f"calibration: {calibration}; markers: {heading}\n"
    )
    print(
        "| scenario | tracker | mean cm | p95 cm | max cm | detection (vis>=0.99) | detection (vis>=0.5) | swaps | "
        "heading median deg (coverage) | ms/frame |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    overall: dict[str, Score] = {m: Score() for m in methods}
    for name in scenarios:
        per: dict[str, Score] = {m: Score() for m in methods}
        for seed in seeds:
            clip = render_clip(name, seed, frames, heading=heading)
            for m in methods:
                per[m].add(run_clip(clip, m, calibration=calibration))
        for m in methods:
            r = per[m].row()
            overall[m].add(per[m])
            print(
                f"| {name} | {m} | {r['mean']:.3f} | {r['p95']:.3f} | {r['max']:.2f} | {100 * r['det']:.2f}% | "
                f"{100 * r['det50']:.2f}% | {int(r['swaps'])} | {r['head']:.2f} ({100 * r['head_cov']:.0f}%) | "
                f"{r['ms']:.2f} |"
            )
        if "paper" in per and "particles" in per:
            a, b = per["particles"].row(), per["paper"].row()
            print(
                f"| {name} | *paper / particles* | *{b['mean'] / a['mean']:.1f}x* | *{b['p95'] / a['p95']:.1f}x* | "
                f"| | | | | *{b['ms'] / a['ms']:.1f}x* |"
            )
    print("\nAll scenarios together:\n")
    print(
        "| tracker | mean cm | p95 cm | max cm | detection | swaps | heading median deg (moving) | "
        "heading median deg (standing, coverage) | ms/frame |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for m in methods:
        r = overall[m].row()
        print(
            f"| {m} | {r['mean']:.3f} | {r['p95']:.3f} | {r['max']:.2f} | {100 * r['det']:.2f}% | {int(r['swaps'])} | "
            f"{r['head']:.2f} | {r['head_still']:.2f} ({100 * r['head_still_cov']:.0f}%) | {r['ms']:.2f} |"
        )


def main() -> None:
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=("stages", "scale", "accuracy", "all"))
    parser.add_argument("--frames", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--counts", default="1,3,8,16,32")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--calibration", choices=("camera", "points"), default="camera")
    parser.add_argument("--heading", choices=("plain", "two_tone"), default="plain", help="Markers on the rovers.")
    args = parser.parse_args()
    print(f"# edge-ips tracking benchmark, {time.strftime('%Y-%m-%d %H:%M')}\n")
    if args.what in ("stages", "all"):
        bench_stages(args.frames or 300, args.seed)
        print()
    if args.what in ("scale", "all"):
        bench_scale(args.frames or 120, [int(c) for c in args.counts.split(",")], args.seed)
        print()
    if args.what in ("accuracy", "all"):
        seeds = [int(s) for s in args.seeds.split(",")]
        bench_accuracy(
            args.scenarios.split(","), args.methods.split(","), seeds, args.frames, args.calibration, args.heading
        )


if __name__ == "__main__":
    main()
