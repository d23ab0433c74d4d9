"""Where the edge fits' centre goes wrong: each fitted side's edge against the truth, by what lies beyond it.

    python benchmarks/bench_edge_sides.py [--scenarios lab,crowd8] [--seeds 1000,16661] [--floor tiles]
        [--off noise,vignetting,colour,awb,jpeg,sharpen,demosaic,motion,exposure] [--per-run]

Each scenario and seed is rendered through the family's camera (``--off``: with those of its effects switched off,
``tracking_runs.without``) and tracked with the edge offsets on (``edge.centre_offsets``, the fits in the frame
loop); every window sent to the fits is kept. For each, the full edge fit (``edge.edges_encoded.fit_edges``, as
the fits run it) is made twice:

* around the **true** centre: each side's fitted edge is then its error, in cm along the side's outward normal
  (+: the marker taken larger on that side). Sides are binned by what lies beyond them, the band beyond the spread
  (``edge.edges_encoded.beyond_level``) over the marker's light: *dark* under 0.5 (a dark body's wall, its top),
  *like* 0.5-1.5, *bright* over 1.5 (the floor beside a dark marker). A fit whose sides err alike on every side
  measures the marker's size wrongly and its centre rightly; sides that err by what lies beyond move the centre
  towards the side that errs outward.
* around the **fast** centre, as the tracker does: the fitted centre's mean error (x, y) and mean |error|, beside
  the fast centre's own.

Per colour over all runs: the median side error per bin, and the two centres' errors. Then per run and rover
(``--per-run``): the mean error (bias) of the fitted and of the fast centre over that rover's fits, and how many
runs' rovers are over the accuracy benchmark's bias bar (0.05 cm). The learned offsets move each frame's fast
centre by what the fits said nearby, so a rover's fitted-centre bias is about the least bias its corrected centre
can have (``docs/benchmarks.md``, session 41).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from tracking_runs import EFFECTS_OFF, frame_of, plane_mapping, render_clip

from edge.centre_offsets import EdgeJob, InlineFits, marker_interior
from edge.edges_encoded import (
    YCC_FROM_BGR,
    EdgeFit,
    SideProfile,
    beyond_level,
    bgr_of_ycc,
    edge_midpoint,
    fit_edges,
    has_band,
    side_profiles,
    srgb_decode,
)
from edge.tracker_config import TrackerConfig
from edge.trackers.factory import build_tracker

BINS = (("dark", 0.0, 0.5), ("like", 0.5, 1.5), ("bright", 1.5, math.inf))
BIAS_BAR_CM = 0.05  # the accuracy benchmark's per-colour bias bar


class KeptFits(InlineFits):
    """The benchmarks' fits, keeping every job handed over."""

    def __init__(self, every_frames: int) -> None:
        super().__init__(every_frames)
        self.jobs: list[EdgeJob] = []

    def submit(self, job: EdgeJob) -> None:
        self.jobs.append(job)
        super().submit(job)


def jobs_of(scenario: str, seed: int, floor: str, off: tuple[str, ...]) -> tuple[str, list[tuple[str, EdgeJob, tuple]]]:
    """The camera's name and every fit job of the run with its rover's id and the truth at its frame
    (``crowd8``: the crowd with the eight-hue palette, as ``bench_tracking.py family`` names it)."""
    eight = scenario == "crowd8"  # the crowd with the eight-hue palette
    clip = render_clip(
        "crowd" if eight else scenario, seed, rovers=8 if eight else None, camera="family", floor=floor, off=off
    )
    config = TrackerConfig(rovers=clip.rovers, fps=clip.fps, edge_offsets=True, camera_sharpens=clip.sharpened)
    fits = KeptFits(config.edge_offsets_every)
    tracker = build_tracker(config, plane_mapping(clip, "camera"), None, fits=fits)  # type: ignore[arg-type]
    for i, image in enumerate(clip.frames):
        tracker.process(frame_of(image, i, clip.fps))
    tracker.close()
    ids = [r.id for r in clip.rovers]
    kept = [
        (ids[j.index], j, clip.truth[j.frame][ids[j.index]]) for j in fits.jobs if ids[j.index] in clip.truth[j.frame]
    ]
    return clip.camera_name, kept


def _fit_at(job: EdgeJob, at: tuple[float, float]) -> tuple[list[SideProfile], tuple[np.ndarray, EdgeFit]] | None:
    """The side profiles around ``at`` and the full fit to them (with the interior's mean Y'CbCr), as the fits make
    it; None when a side does not reach its band."""
    interior = marker_interior(job, at)
    profiles = side_profiles(job.raw, job.xy_cm, at, job.axis_rad, (job.size_cm[0] / 2, job.size_cm[1] / 2))
    if not interior.any() or not all(has_band(p) for p in profiles):
        return None
    marker_ycc = job.raw[interior].astype(np.float64).mean(axis=0) @ YCC_FROM_BGR.T
    fit = fit_edges(profiles, marker_ycc, side_levels=True, weigh_channels=job.sharpened)  # as the tracker's
    return profiles, (marker_ycc, fit)


def measure(kept: list[tuple[str, EdgeJob, tuple]]) -> dict[str, dict[str, list]]:
    """Per colour: side errors (beyond over marker, cm) and per job the fast and fitted centres' errors."""
    out: dict[str, dict[str, list]] = {}
    for rid, job, truth in kept:
        row = out.setdefault(rid, {"sides": [], "centres": []})
        at_truth = _fit_at(job, (truth[0], truth[1]))
        if at_truth is not None:
            profiles, (marker_ycc, fit) = at_truth
            marker = float(srgb_decode(np.clip(bgr_of_ycc(marker_ycc), 0, 1)).sum())
            for j, p in enumerate(profiles):
                beyond = float(beyond_level(p, srgb_decode).sum())
                row["sides"].append((beyond / max(marker, 1e-9), fit.u0_px[j] / p.px_per_cm))
        at_fast = _fit_at(job, job.centre_cm)
        if at_fast is not None:
            profiles, (_, fit) = at_fast
            x, y = edge_midpoint(job.centre_cm, job.axis_rad, fit.u0_px, profiles)
            fx, fy = job.centre_cm
            row["centres"].append((fx - truth[0], fy - truth[1], x - truth[0], y - truth[1]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default="lab,crowd8")
    parser.add_argument("--seeds", default="1000,16661")
    parser.add_argument("--floor", default="tiles")
    parser.add_argument("--off", default="", help=f"effects switched off: {', '.join(EFFECTS_OFF)}")
    parser.add_argument("--per-run", action="store_true", help="each run's and rover's fitted and fast centre bias")
    args = parser.parse_args()
    off = tuple(n for n in args.off.split(",") if n)
    unknown = sorted(set(off) - set(EFFECTS_OFF))
    if unknown:
        parser.error(f"unknown effects {', '.join(unknown)}: choose from {', '.join(EFFECTS_OFF)}")
    total: dict[str, dict[str, list]] = {}
    runs: list[tuple[str, int, str, np.ndarray]] = []
    print(f"# edge fits' sides, floor {args.floor}" + (f", without {', '.join(off)}" if off else ""))
    for scenario in args.scenarios.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            name, kept = jobs_of(scenario, seed, args.floor, off)
            print(f"{scenario} {seed}: {name}, {len(kept)} fits", file=sys.stderr, flush=True)
            for rid, row in measure(kept).items():
                for key, values in row.items():
                    total.setdefault(rid, {"sides": [], "centres": []})[key] += values
                if row["centres"]:
                    runs.append((scenario, seed, rid, np.array(row["centres"]).reshape(-1, 4)))
    print("\n| colour | " + " | ".join(f"{b} sides: n, median cm" for b, _, _ in BINS), end="")
    print(" | fast centre mean x, y cm (mean abs) | fitted centre mean x, y cm (mean abs) |")
    print("|---|" + "---|" * (len(BINS) + 2))
    for rid in sorted(total):
        sides = np.array(total[rid]["sides"]).reshape(-1, 2)
        cells = []
        for _, lo, hi in BINS:
            sel = (sides[:, 0] >= lo) & (sides[:, 0] < hi)
            cells.append(f"{int(sel.sum())}, {np.median(sides[sel, 1]):+.3f}" if sel.any() else "0, -")
        c = np.array(total[rid]["centres"]).reshape(-1, 4)
        if len(c):
            fast = f"{c[:, 0].mean():+.3f}, {c[:, 1].mean():+.3f} ({np.hypot(c[:, 0], c[:, 1]).mean():.3f})"
            fitted = f"{c[:, 2].mean():+.3f}, {c[:, 3].mean():+.3f} ({np.hypot(c[:, 2], c[:, 3]).mean():.3f})"
        else:
            fast = fitted = "-"
        print(f"| {rid} | " + " | ".join(cells) + f" | {fast} | {fitted} |")
    if args.per_run:
        print_per_run(runs)


def print_per_run(runs: list[tuple[str, int, str, np.ndarray]]) -> None:
    """Each run's and rover's bias (mean error x, y over its fits) of the fitted and of the fast centre, and how
    many are over :data:`BIAS_BAR_CM`."""
    if not runs:
        print("\nNo run's rover had a fit to compare.")
        return
    print("\n| scenario | seed | colour | fits | fitted centre bias x, y cm (size) | fast centre bias x, y cm (size) |")
    print("|---|---|---|---|---|---|")
    fitted_sizes, fast_sizes = [], []
    for scenario, seed, rid, c in runs:
        fast, fitted = c[:, :2].mean(axis=0), c[:, 2:].mean(axis=0)
        fast_sizes.append(float(np.hypot(*fast)))
        fitted_sizes.append(float(np.hypot(*fitted)))
        print(
            f"| {scenario} | {seed} | {rid} | {len(c)} | {fitted[0]:+.3f}, {fitted[1]:+.3f} ({fitted_sizes[-1]:.3f}) "
            f"| {fast[0]:+.3f}, {fast[1]:+.3f} ({fast_sizes[-1]:.3f}) |"
        )
    n = len(runs)
    over_fitted = sum(b > BIAS_BAR_CM for b in fitted_sizes)
    over_fast = sum(b > BIAS_BAR_CM for b in fast_sizes)
    print(
        f"\nRuns' rovers: {n}; bias over {BIAS_BAR_CM} cm: fitted centre {over_fitted} (mean size "
        f"{np.mean(fitted_sizes):.3f} cm), fast centre {over_fast} (mean size {np.mean(fast_sizes):.3f} cm)"
    )


if __name__ == "__main__":
    main()
