"""Which frames of one family run miss a visible rover or misplace one: the per-frame view behind a family row.

    python benchmarks/bench_frames.py --scenario occlusion --seed 11404 [--min-error 1.0] [--rovers red,green]

Tracks one family clip (``bench_tracking.py family``'s camera for that scenario and seed, the default tracker with
``edge_offsets``, the fits in the loop held back as a worker would deliver them) and prints one line per rover and
frame where the marker was wholly in view (visible >= 0.99) and got no pose, or where a pose was reported more than
``--min-error`` cm from the truth (at any visibility: the family's error figures count every reported pose), with
the rover's visibility, speed and the pose's quality; then the runs of consecutive frames per rover. A row of the
family table that misses detection or has a ghost is read here first, then the blobs of those frames
(``edge.rover_track.RoverTrack.whole_marker``) in a debugger.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402

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


def frames(scenario: str, seed: int, min_error_cm: float, rovers: list[str] | None) -> None:
    clip = family_clip(scenario, seed, None)
    config = TrackerConfig(
        rovers=clip.rovers, method="particles", fps=clip.fps, edge_offsets=True, camera_sharpens=clip.sharpened
    )
    tracker = build_tracker(config, plane_mapping(clip, "camera"), None, fits=InlineFits(config.edge_offsets_every))  # type: ignore[arg-type]
    print(f"{scenario} seed {seed}: {clip.camera_name} ({len(clip.frames)} frames)\n")  # type: ignore[attr-defined]
    print("| frame | rover | visible | speed cm/s | pose |")
    print("|---|---|---|---|---|")
    flagged: dict[str, list[int]] = {}
    for i, image in enumerate(clip.frames):  # type: ignore[attr-defined]
        got = {e.rover_id: e for e in tracker.process(frame_of(image, i, clip.fps)).estimates}  # type: ignore[attr-defined]
        for rid, (x, y, _th, vx, vy, visible) in clip.truth[i].items():  # type: ignore[attr-defined]
            if rovers and rid not in rovers:
                continue
            e = got.get(rid)
            if e is None and visible >= 0.99:
                what = "missing"
            elif e is not None and (error := math.hypot(e.x_cm - x, e.y_cm - y)) > min_error_cm:
                what = f"{error:.2f} cm off (quality {e.quality:.2f})"
            else:
                continue
            flagged.setdefault(rid, []).append(i)
            print(f"| {i} | {rid} | {visible:.2f} | {math.hypot(vx, vy):.0f} | {what} |")
    print("\n| rover | frames flagged | runs (first-last) |")
    print("|---|---|---|")
    for rid, idx in flagged.items():
        runs: list[list[int]] = []
        for i in idx:
            if runs and i == runs[-1][1] + 1:
                runs[-1][1] = i
            else:
                runs.append([i, i])
        text = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs)
        print(f"| {rid} | {len(idx)} | {text} |")


def main() -> None:
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="occlusion", help="a family scenario (lab, lens, occlusion, ..., crowd8)")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--min-error", type=float, default=1.0, help="flag poses farther than this from the truth (cm)")
    parser.add_argument("--rovers", default=None, help="rover ids to look at, comma-separated (default: all)")
    args = parser.parse_args()
    frames(args.scenario, args.seed, args.min_error, args.rovers.split(",") if args.rovers else None)


if __name__ == "__main__":
    main()
