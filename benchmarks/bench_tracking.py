"""Tracking benchmarks: Table IV stage times, scaling with rover count, Table V accuracy, and accuracy over the
simulator's camera family.

    python benchmarks/bench_tracking.py stages   [--frames N] [--seed S] [--baseline OTHER_CHECKOUT [--reps R]]
    python benchmarks/bench_tracking.py scale    [--frames N] [--counts 1,3,8,16,32]
    python benchmarks/bench_tracking.py accuracy [--scenarios lab,...] [--methods ...] [--seeds 0,1] [--frames N]
                                                 [--calibration camera|points|targets] [--heading plain|two_tone]
    python benchmarks/bench_tracking.py family   [--scenarios lab,...,crowd8] [--seeds 0,1] [--frames N]
                                                 [--calibration camera|points|targets] [--detail] [--chroma 4:4:4]
                                                 [--quality 95] [--floor tiles|beige|wood|white|dark]
    python benchmarks/bench_tracking.py acquire  [--seed S] [--reps R]
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

``acquire``: the reacquisition pass's cost per lost rover (``edge.acquisition``: the 1/4-resolution view, then each
rover's candidates), on the first frame of the family's twelve-hue crowd clip on each floor; it runs only while a
rover is lost.

``family``: every scenario through a camera of the simulator's family drawn from the seed (chroma sampling, JPEG
quality, blur, tone curve, crosstalk, white balance, noise, vignetting; the rovers' body colours, height and
margins: ``edge.sim.cameras``), the default tracker; per scenario and camera, per marker colour: mean, p95, max,
bias (x, y), detection, swaps, ghosts, heading median / p95, and whether the bars hold (mean <= 0.15 cm,
p95 <= 0.4 cm, detection >= 99.5 %, no swap, no ghost, every colour's bias <= 0.05 cm). ``crowd8`` is the crowd
scenario with the eight-hue palette. Seeds 0-99 were used while developing; report held-out seeds (1000 and up).
Scoring: ``benchmarks/tracking_runs.py``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

# the checkout this script is in, ahead of an installed edge (an editable install may be another checkout's): a
# benchmark measures the code beside it, unless PYTHONPATH says which (stages --baseline runs another checkout so)
if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tracking_runs import Score, frame_of, plane_mapping, render_clip, run_clip, summary  # noqa: E402

from edge.acquisition import candidates, low_resolution_view  # noqa: E402
from edge.centre_offsets import KEEP, EdgeSample, OffsetMap  # noqa: E402
from edge.sim.scene import FLOORS  # noqa: E402
from edge.tracker_config import TrackerConfig  # noqa: E402
from edge.trackers.base import CameraPlaneMapping  # noqa: E402
from edge.trackers.factory import build_tracker  # noqa: E402

SCENARIOS = ("lab", "drift", "sun", "cross", "occlusion", "lens", "crowd")
FAMILY_SCENARIOS = (*SCENARIOS, "daylight", "crowd8")
BARS = {"mean": 0.15, "p95": 0.4, "det": 0.995, "bias": 0.05}
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
    ("Marker edges (axis; with outline_fit the centre too)", ("outline",)),
    ("Search windows", ("window",)),
    ("Reacquisition pass (1/4 resolution)", ("acquire",)),
    ("Filter, identity, heading", ("filter",)),
    ("Edge offsets (edge_offsets: copy a window, apply offsets)", ("offsets",)),
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


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, OpenCV {cv2.__version__}"


# -- stages (Table IV) --------------------------------------------------------------------------------------------
def bench_stages(frames: int, seed: int, outline_fit: bool, edge_offsets: bool = False) -> None:
    clip = render_clip("lab", seed, frames)
    offsets = "worker" if edge_offsets else False  # the fits in their worker process, as the appliance runs them
    score = run_clip(clip, "particles", use_background=False, outline_fit=outline_fit, edge_offsets=offsets)
    paper = run_clip(clip, "paper")
    print(f"## Table IV: stage times, 1280x720, 3 rovers, one core ({machine()})")
    print(
        f"outline_fit = {str(outline_fit).lower()}, edge_offsets = {str(edge_offsets).lower()}; lab scenario seed "
        f"{seed}, {len(clip.frames)} frames; median (and 95th percentile) ms per frame\n"
    )
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
    if edge_offsets:
        offset_cost()
        inline = run_clip(clip, "particles", use_background=False, outline_fit=outline_fit, edge_offsets=True)
        fits = [f["offsets"] for f in inline.stages if f.get("offsets", 0.0) > 10.0]  # the frames that ran a fit
        if fits:
            print(
                f"one edge fit (what the worker does per job; here in the loop): median {np.median(fits):.0f} ms, "
                f"p95 {np.percentile(fits, 95):.0f} ms, {len(fits)} fits in {len(inline.stages)} frames"
            )


def offset_cost() -> None:
    """The per-rover, per-frame cost of applying a learned offset once a rover has its full store of samples (the
    stages run above is over before the worker's first fits come back)."""
    rng = np.random.default_rng(0)
    offsets = OffsetMap()
    for k in range(KEEP):
        xy = rng.uniform(0.0, 400.0, 2)
        offsets.add(EdgeSample(0, k, (float(xy[0]), float(xy[1])), (0.1, -0.2 + 0.05 * float(rng.standard_normal()))))
    offsets.offset(200.0, 200.0)  # the samples' arrays are built once after each new sample
    t0 = time.perf_counter()
    for k in range(1000):
        offsets.offset(100.0 + 0.1 * k, 200.0)
    per_call = (time.perf_counter() - t0) / 1000 * 1e3
    print(f"applying a learned offset ({KEEP} samples): {per_call:.4f} ms per rover per frame")


def compare_stages(frames: int, seed: int, baseline: str, reps: int) -> None:
    """The same clip through this checkout's tracker and ``baseline``'s (another checkout of the repository), each in
    its own process, runs interleaved (A B, B A, ...) so that a shared machine's load falls on both alike: per stage
    the median over runs of each run's median ms per frame, the ratio, and whether the poses are the same."""
    import json
    import pickle
    import subprocess
    import tempfile

    clip = render_clip("lab", seed, frames)
    roots = {"this": str(Path(__file__).resolve().parent.parent), "baseline": str(Path(baseline).resolve())}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "clip.pkl"
        path.write_bytes(pickle.dumps(clip))
        workers = {
            name: subprocess.Popen(
                [sys.executable, __file__, "_stage_worker", str(path)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                env={**os.environ, "PYTHONPATH": root},
            )
            for name, root in roots.items()
        }
        runs: dict[str, list[dict]] = {name: [] for name in roots}
        for rep in range(reps):
            for name in ("this", "baseline") if rep % 2 == 0 else ("baseline", "this"):
                pipe_in, pipe_out = workers[name].stdin, workers[name].stdout
                assert pipe_in is not None and pipe_out is not None
                pipe_in.write("run\n")
                pipe_in.flush()
                runs[name].append(json.loads(pipe_out.readline()))
        for w in workers.values():
            w.communicate("")
    a, b = runs["this"][0]["poses"], runs["baseline"][0]["poses"]
    same_ids = all([e[0] for e in fa] == [e[0] for e in fb] for fa, fb in zip(a, b, strict=True))
    diff = 0.0
    for fa, fb in zip(a, b, strict=True):
        for ea, eb in zip(fa, fb, strict=False):  # the same rovers: checked above
            diff = max([diff, *(abs(u - v) for u, v in zip(ea[1:], eb[1:], strict=True))])
    print(f"## Stage times against {roots['baseline']} ({machine()})")
    print(f"lab scenario seed {seed}, {len(clip.frames)} frames, {reps} runs each, interleaved; median over runs of")
    print(" each run's median ms per frame (first 5 frames left out)\n")
    print(f"poses: same rovers in every frame: {same_ids}; largest difference {diff:.2g} (cm, rad, cm/s)\n")
    print("| stage | this checkout | baseline | this / baseline |")
    print("|---|---|---|---|")
    stages = sorted({k for r in runs["this"] + runs["baseline"] for f in r["stages"] for k in f})
    for stage in stages:
        med = {
            n: float(np.median([np.median([f.get(stage, 0.0) for f in r["stages"][5:]]) for r in runs[n]]))
            for n in runs
        }
        ratio = f"{med['this'] / med['baseline']:.2f}" if med["baseline"] > 0 else ""
        print(f"| {stage} | {med['this']:.3f} | {med['baseline']:.3f} | {ratio} |")


def stage_worker(clip_path: str) -> None:
    """``compare_stages``' worker: tracks the pickled clip with this process's ``edge`` on each ``run`` line."""
    import json
    import pickle

    clip = pickle.loads(Path(clip_path).read_bytes())
    for _ in sys.stdin:
        config = TrackerConfig(rovers=clip.rovers, method="particles", fps=clip.fps)
        tracker = build_tracker(config, CameraPlaneMapping(clip.camera, clip.height_cm), None)
        stages, poses = [], []
        for i, image in enumerate(clip.frames):
            t0 = time.perf_counter()
            result = tracker.process(frame_of(image, i, clip.fps))
            stages.append({**result.stage_ms, "wall": (time.perf_counter() - t0) * 1e3})
            poses.append([[e.rover_id, e.x_cm, e.y_cm, e.theta_rad or 0.0, e.quality] for e in result.estimates])
        print(json.dumps({"stages": stages, "poses": poses}), flush=True)


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


def bench_acquire(seed: int, reps: int) -> None:
    """The acquisition pass's time on the first frame of the family's crowd clip for ``seed`` on every floor: the
    low-resolution view once per frame, the candidates once per lost rover (median of ``reps`` runs)."""
    print(f"## Acquisition pass ({machine()})")
    print(f"family crowd clip seed {seed}, first frame, 12 rovers, median of {reps} runs\n")
    print("| floor | view ms | candidates ms per rover (median / max) | places tried per rover (mean) |")
    print("|---|---|---|---|")
    for floor in FLOORS:
        clip = render_clip("crowd", seed, 1, camera="family", floor=floor)  # type: ignore[arg-type]
        config = TrackerConfig(rovers=clip.rovers, method="particles", fps=clip.fps)
        tracker = build_tracker(config, plane_mapping(clip, "camera"), None)
        tracker.process(frame_of(clip.frames[0], 0, clip.fps))  # the scale, the local white
        image, scale = clip.frames[0], tracker.acquire_scale
        view_ms, per_rover, places = [], [], []
        for _ in range(reps):
            t0 = time.perf_counter()
            view = low_resolution_view(image, scale, tracker.colors, tracker.white)
            view_ms.append((time.perf_counter() - t0) * 1e3)
            for k in range(len(clip.rovers)):
                t1 = time.perf_counter()
                places.append(len(candidates(view, k, tracker.colors)))
                per_rover.append((time.perf_counter() - t1) * 1e3)
        rover_ms = np.median(np.reshape(per_rover, (reps, -1)), axis=0)
        print(
            f"| {floor} | {np.median(view_ms):.2f} | {np.median(rover_ms):.2f} / {np.max(rover_ms):.2f} "
            f"| {np.mean(places):.1f} |"
        )


def family_clip(
    name: str,
    seed: int,
    frames: int | None,
    chroma: str | None = None,
    quality: int | None = None,
    sharpen: float | None = None,
    demosaic: str | None = None,
    floor: str = "tiles",
) -> object:
    """Scenario ``name`` (``crowd8``: the crowd with the eight-hue palette) through the family's camera for ``seed``
    (``chroma``, ``quality``, ``sharpen``, ``demosaic``: with that JPEG chroma sampling or quality, or that
    processor's sharpening or demosaicing, instead of the camera's own; ``floor``: on that floor,
    ``edge.sim.scene.FLOORS``)."""
    overrides = {"chroma": chroma, "quality": quality, "sharpen": sharpen, "demosaic": demosaic, "floor": floor}
    if name == "crowd8":
        clip = render_clip("crowd", seed, frames, rovers=8, camera="family", **overrides)  # type: ignore[arg-type]
        clip.name = "crowd8"
        return clip
    return render_clip(name, seed, frames, camera="family", **overrides)  # type: ignore[arg-type]


def bars_hold(r: dict[str, float], per_colour: list[dict[str, float]]) -> list[str]:
    """The bars this row misses (empty: all hold)."""
    missed = []
    if not r["mean"] <= BARS["mean"]:
        missed.append("mean")
    if not r["p95"] <= BARS["p95"]:
        missed.append("p95")
    if not r["det"] >= BARS["det"]:
        missed.append("detection")
    if r["swaps"] > 0:
        missed.append("swaps")
    if r["ghosts"] > 0:
        missed.append("ghosts")
    if any(not c["bias"] <= BARS["bias"] for c in per_colour if c["bias"] == c["bias"]):
        missed.append("bias")
    return missed


def bench_family(
    scenarios: list[str],
    seeds: list[int],
    frames: int | None,
    calibrations: list[str],
    detail: bool,
    outline_fit: bool = False,
    chroma: str | None = None,
    quality: int | None = None,
    edge_offsets: bool = False,
    sharpen: float | None = None,
    demosaic: str | None = None,
    floor: str = "tiles",
) -> None:
    """Render each scenario and seed once through the family's camera (on ``floor``), track it with each
    calibration, print a table per calibration."""
    runs: dict[str, list[tuple[object, Score]]] = {c: [] for c in calibrations}
    for name in scenarios:
        for seed in seeds:
            clip = family_clip(name, seed, frames, chroma, quality, sharpen, demosaic, floor)
            about = SimpleNamespace(name=name, seed=seed, camera_name=clip.camera_name, bodies=clip.bodies)  # type: ignore[attr-defined]
            for c in calibrations:
                score = run_clip(clip, "particles", calibration=c, outline_fit=outline_fit, edge_offsets=edge_offsets)  # type: ignore[arg-type]
                runs[c].append((about, score))
            print(f"{name} seed {seed}: {clip.camera_name}", file=sys.stderr, flush=True)  # type: ignore[attr-defined]
    print(f"tracker settings outline_fit = {str(outline_fit).lower()}, edge_offsets = {str(edge_offsets).lower()}\n")
    for c in calibrations:
        family_table(runs[c], seeds, frames, c, detail)
        print()


def family_table(
    runs: list[tuple[object, Score]], seeds: list[int], frames: int | None, calibration: str, detail: bool
) -> None:
    print(f"## Accuracy over the camera family, calibration: {calibration} ({machine()})")
    print(
        f"seeds {','.join(map(str, seeds))}; {'all' if frames is None else frames} frames per run; tracker: particles "
        "(default); one camera of the family per scenario and seed\n"
    )
    print(
        "| scenario | seed | camera | bodies | mean cm | p95 cm | max cm | worst colour bias cm | detection | swaps | "
        "ghosts | heading median / p95 deg | bars |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    colours: dict[str, Score] = {}
    details: list[str] = []
    total = Score()
    missed_runs = 0
    for clip, score in runs:
        name, seed = clip.name, clip.seed  # type: ignore[attr-defined]
        total.add(score)
        r = score.row()
        per = {rid: summary(s) for rid, s in score.rovers.items()}
        worst = max(per, key=lambda k: per[k]["bias"] if per[k]["bias"] == per[k]["bias"] else -1.0)
        missed = bars_hold(r, list(per.values()))
        missed_runs += bool(missed)
        print(
            f"| {name} | {seed} | {clip.camera_name} | {clip.bodies} | {r['mean']:.3f} | {r['p95']:.3f} | "  # type: ignore[attr-defined]
            f"{r['max']:.2f} | {per[worst]['bias']:.3f} ({worst}) | {100 * r['det']:.2f}% | {int(r['swaps'])} | "
            f"{int(r['ghosts'])} | {r['head']:.2f} / {r['head_p95']:.2f} | "
            f"{'ok' if not missed else 'missed: ' + ', '.join(missed)} |"
        )
        for rid, s in score.rovers.items():
            colours.setdefault(rid, Score()).rover(rid).add(s)
            c = per[rid]
            details.append(
                f"| {name} | {seed} | {rid} | {c['mean']:.3f} | {c['p95']:.3f} | {c['max']:.2f} | "
                f"{c['bias_x']:+.3f}, {c['bias_y']:+.3f} | {100 * c['det']:.2f}% | {int(c['swaps'])} | "
                f"{int(c['ghosts'])} | {c['head']:.2f} / {c['head_p95']:.2f} |"
            )
    print(f"\nRuns missing a bar: {missed_runs} of {len(runs)}\n")
    print("Per marker colour, all scenarios and cameras together:\n")
    print(
        "| colour | mean cm | p95 cm | max cm | bias x, y cm | detection | swaps | ghosts | heading median / p95 deg |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for rid, sc in colours.items():
        c = summary(sc.total())
        print(
            f"| {rid} | {c['mean']:.3f} | {c['p95']:.3f} | {c['max']:.2f} | {c['bias_x']:+.3f}, {c['bias_y']:+.3f} | "
            f"{100 * c['det']:.2f}% | {int(c['swaps'])} | {int(c['ghosts'])} | {c['head']:.2f} / {c['head_p95']:.2f} |"
        )
    t = total.row()
    print(
        f"| **all** | {t['mean']:.3f} | {t['p95']:.3f} | {t['max']:.2f} | | {100 * t['det']:.2f}% | "
        f"{int(t['swaps'])} | {int(t['ghosts'])} | {t['head']:.2f} / {t['head_p95']:.2f} |"
    )
    print(f"\nProcessing: median {t['ms']:.2f} ms per frame (measured under load: to re-run on a quiet machine)")
    if detail:
        print("\nEvery scenario, camera and colour:\n")
        print(
            "| scenario | seed | colour | mean cm | p95 cm | max cm | bias x, y cm | detection | swaps | ghosts | "
            "heading median / p95 deg |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        print("\n".join(details))


def main() -> None:
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    if sys.argv[1:2] == ["_stage_worker"]:
        stage_worker(sys.argv[2])
        return
    parser.add_argument("what", choices=("stages", "scale", "accuracy", "family", "acquire", "all"))
    parser.add_argument("--frames", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--counts", default="1,3,8,16,32")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--calibration", choices=("camera", "points", "targets", "both"), default="camera")
    parser.add_argument("--heading", choices=("plain", "two_tone"), default="plain", help="Markers on the rovers.")
    parser.add_argument(
        "--outline-fit", action="store_true", help="stages, family: track with outline_fit = true (default: false)"
    )
    parser.add_argument(
        "--edge-offsets",
        action="store_true",
        help="stages, family: track with edge_offsets = true (default: false; stages: the fits in a worker process, "
        "family: in the loop, their results held back as a worker would deliver them)",
    )
    parser.add_argument("--detail", action="store_true", help="family: a row per scenario, camera and colour")
    parser.add_argument(
        "--baseline",
        default=None,
        help="stages: compare with the tracker of this other checkout (e.g. of main), runs interleaved",
    )
    parser.add_argument("--reps", type=int, default=10, help="stages --baseline: runs of each tracker; acquire: runs")
    parser.add_argument(
        "--chroma",
        choices=("4:2:0", "4:2:2", "4:4:4"),
        default=None,
        help="family: every camera with this JPEG chroma sampling instead of its own (all else kept)",
    )
    parser.add_argument(
        "--quality",
        type=int,
        choices=range(1, 101),
        metavar="1-100",
        default=None,
        help="family: every camera with this JPEG quality instead of its own (all else kept)",
    )
    parser.add_argument(
        "--sharpen",
        type=float,
        default=None,
        help="family: every camera's processor sharpening by this much instead of its own (0: none; all else kept)",
    )
    parser.add_argument(
        "--demosaic",
        choices=("bilinear", "edge-aware", "none"),
        default=None,
        help="family: every camera's processor demosaicing so instead of its own (none: no Bayer filter)",
    )
    parser.add_argument(
        "--floor",
        choices=tuple(FLOORS),
        default="tiles",
        help="family: every scenario on a floor of this material instead of the default grey tiles",
    )
    args = parser.parse_args()
    if args.sharpen is not None and not 0.0 <= args.sharpen <= 4.0:
        parser.error("--sharpen must be 0-4")
    print(f"# edge-ips tracking benchmark, {time.strftime('%Y-%m-%d %H:%M')}\n")
    if args.what == "stages" and args.baseline is not None:
        compare_stages(args.frames or 150, args.seed, args.baseline, args.reps)
        return
    if args.what in ("stages", "all"):
        bench_stages(args.frames or 300, args.seed, args.outline_fit, args.edge_offsets)
        print()
    if args.what in ("scale", "all"):
        bench_scale(args.frames or 120, [int(c) for c in args.counts.split(",")], args.seed)
        print()
    if args.what == "acquire":
        bench_acquire(args.seed, args.reps)
    if args.what in ("accuracy", "all"):
        if args.calibration == "both":
            parser.error("--calibration both is for the family table")
        seeds = [int(s) for s in args.seeds.split(",")]
        bench_accuracy(
            args.scenarios.split(","), args.methods.split(","), seeds, args.frames, args.calibration, args.heading
        )
    if args.what == "family":
        seeds = [int(s) for s in args.seeds.split(",")]
        scenarios = args.scenarios.split(",") if args.scenarios != ",".join(SCENARIOS) else list(FAMILY_SCENARIOS)
        calibrations = ["camera", "points"] if args.calibration == "both" else [args.calibration]
        bench_family(
            scenarios,
            seeds,
            args.frames,
            calibrations,
            args.detail,
            args.outline_fit,
            args.chroma,
            args.quality,
            args.edge_offsets,
            args.sharpen,
            args.demosaic,
            args.floor,
        )


if __name__ == "__main__":
    main()
