"""Where a colour's bias comes from over a run: the fast centre's error and the edge offsets applied, span by span.

    python benchmarks/bench_offsets_timeline.py --scenario lab --seed 2008 [--colours blue,green] [--spans 0,60,200]

Tracks one family clip (``bench_tracking.py family``'s camera for that scenario and seed, ``edge_offsets = true``,
the fits in the loop with their results held back as a worker would deliver them) and prints, per rover and span of
frames (the marker wholly in view), the mean of: the pose's error (the bias the family table reports), the offset
``edge.centre_offsets`` applied, and the fast centre's error (the measurement less that offset), x and y in cm; and
the rover's mean y on the floor (the far side is y 400-550). An offset with the fast centre's sign, or one where the
fast centre has no error, adds bias instead of taking it out.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

# the checkout this script is in, ahead of an installed edge (an editable install may be another checkout's): a
# benchmark measures the code beside it, unless PYTHONPATH says which (stages --baseline runs another checkout so)
if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_tracking import family_clip  # noqa: E402
from tracking_runs import frame_of, plane_mapping  # noqa: E402

from edge.centre_offsets import InlineFits  # noqa: E402
from edge.tracker_config import TrackerConfig  # noqa: E402
from edge.trackers.factory import build_tracker  # noqa: E402


def timeline(scenario: str, seed: int, colours: list[str] | None, spans: list[int]) -> None:
    clip = family_clip(scenario, seed, None)
    config = TrackerConfig(
        rovers=clip.rovers, method="particles", fps=clip.fps, edge_offsets=True, camera_sharpens=clip.sharpened
    )
    tracker = build_tracker(config, plane_mapping(clip, "camera"), None, fits=InlineFits(config.edge_offsets_every))  # type: ignore[arg-type]
    tracks = {t.config.id: t for t in tracker.tracks}  # type: ignore[attr-defined]
    watch = colours or list(tracks)
    rows: dict[str, list[tuple[float, ...]]] = {rid: [] for rid in watch}
    frames = clip.frames  # type: ignore[attr-defined]
    for i, image in enumerate(frames):
        got = {e.rover_id: e for e in tracker.process(frame_of(image, i, clip.fps)).estimates}  # type: ignore[attr-defined]
        for rid in watch:
            x, y, _th, _vx, _vy, visible = clip.truth[i][rid]  # type: ignore[attr-defined]
            e = got.get(rid)
            if e is None or visible < 0.99 or e.measured_xy_cm is None:
                continue
            ox, oy = tracks[rid].offset_cm
            mx, my = e.measured_xy_cm
            rows[rid].append((i, e.x_cm - x, e.y_cm - y, ox, oy, mx - ox - x, my - oy - y, y))
    print(f"{scenario} seed {seed}: {clip.camera_name} ({len(frames)} frames)\n")  # type: ignore[attr-defined]
    print("| rover | frames | n | pose error x, y | offset applied x, y | fast centre's error x, y | mean y |")
    print("|---|---|---|---|---|---|---|")
    edges = [*spans, len(frames)]
    for rid in watch:
        a = np.asarray(rows[rid]) if rows[rid] else np.zeros((0, 8))
        for lo, hi in [*itertools.pairwise(edges), (0, len(frames))]:
            s = a[(a[:, 0] >= lo) & (a[:, 0] < hi)]
            if len(s) == 0:
                continue
            span = "all" if (lo, hi) == (0, len(frames)) else f"{lo}-{hi - 1}"
            m = s.mean(axis=0)
            print(
                f"| {rid} | {span} | {len(s)} | {m[1]:+.3f}, {m[2]:+.3f} | {m[3]:+.3f}, {m[4]:+.3f} | "
                f"{m[5]:+.3f}, {m[6]:+.3f} | {m[7]:.0f} |"
            )


def main() -> None:
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="lab", help="a family scenario (lab, lens, occlusion, ..., crowd8)")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--colours", default=None, help="rover ids (colours) to follow, comma-separated (default: all)")
    parser.add_argument("--spans", default="0,30,60,120,200,300", help="first frames of the spans, comma-separated")
    args = parser.parse_args()
    spans = sorted({int(v) for v in args.spans.split(",")} | {0})
    timeline(args.scenario, args.seed, args.colours.split(",") if args.colours else None, spans)


if __name__ == "__main__":
    main()
