#!/usr/bin/env python3
"""``edge-ips track`` on a video, with the edge fits (``edge_offsets``) as the default leaves them and off.

    .venv/bin/python benchmarks/bench_track_video.py [--scenario lab] [--seed 0] [--frames 450]

The simulator renders the scenario into a directory as ``edge-ips sim render`` does (an MPEG-4 part 2 video, as
``cv2.VideoWriter`` writes it: 4:2:0 chroma, so the fits' ``auto`` is on for it), then the video is tracked with
the scene's own ``camera.json`` twice: ``edge_offsets = "auto"`` (the default: a video file's frames came through
a codec) and ``false``. Reported per run: the wall time per frame (decode, tracking and, with the fits, the time the
frame loop waits for them: ``track`` runs them in worker processes but takes each result at a set frame, so its poses
repeat), and per rover the mean, p95 and bias (x, y) of the poses against ``truth.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from edge.offline import track_video  # noqa: E402  (after the sys.path line above)
from edge.sim.export import render_to_directory  # noqa: E402
from edge.tracker_config import DEFAULT_ROVERS, TrackerConfig  # noqa: E402


def score(poses: Path, truth_csv: Path) -> dict[str, tuple[float, float, float, float]]:
    """Per rover: mean and p95 distance (cm) of its poses from the truth of their frame, and the bias (x, y)."""
    truth = {(int(r["frame"]), r["id"]): (float(r["x"]), float(r["y"])) for r in csv.DictReader(truth_csv.open())}
    offsets: dict[str, list[tuple[float, float]]] = {}
    for line in poses.open():
        pose = json.loads(line)
        where = truth.get((pose["frame"], pose["id"]))
        if where is not None:
            offsets.setdefault(pose["id"], []).append((pose["x"] - where[0], pose["y"] - where[1]))
    out = {}
    for rover, pairs in sorted(offsets.items()):
        d = np.array(pairs)
        e = np.hypot(d[:, 0], d[:, 1])
        out[rover] = (float(e.mean()), float(np.percentile(e, 95)), float(d[:, 0].mean()), float(d[:, 1].mean()))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="lab")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=450)
    args = parser.parse_args()
    print(f"# edge-ips track on a video, {datetime.now(UTC):%Y-%m-%d %H:%M} UTC")
    print(f"{platform.machine()}, Python {platform.python_version()}; scenario {args.scenario} seed {args.seed}\n")
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp)
        render_to_directory(args.scenario, run, frames=args.frames, seed=args.seed)
        print("| edge_offsets | frames | wall ms per frame | rover | mean cm | p95 cm | bias x, y cm |")
        print("|---|---|---|---|---|---|---|")
        for setting in ("auto", False):
            config = TrackerConfig(rovers=DEFAULT_ROVERS, edge_offsets=setting)
            out = run / f"poses-{setting}.jsonl"
            t0 = time.perf_counter()
            summary = track_video(run / "video.mp4", run / "camera.json", out, config)
            ms = (time.perf_counter() - t0) * 1e3 / max(summary.frames, 1)
            for rover, (mean, p95, bx, by) in score(out, run / "truth.csv").items():
                name = f'"{setting}"' if setting == "auto" else str(setting).lower()
                row = f"| {name} | {summary.frames} | {ms:.1f} | {rover} | {mean:.3f} | {p95:.3f}"
                print(f"{row} | {bx:+.3f}, {by:+.3f} |")


if __name__ == "__main__":
    main()
