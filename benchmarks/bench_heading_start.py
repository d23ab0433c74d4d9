"""One-colour headings the tracker could not know: reported for a rover standing still, and turned round.

    python benchmarks/bench_heading_start.py [--scenarios lab,cross,crowd8,...] [--seeds 1000] [--frames N]

A one-colour marker's axis says nothing of which end is the front; the direction of motion does, once the rover
drives. Per family run (``bench_tracking.py family``'s camera for the scenario and seed, the default tracker), over
the rover frames with a pose: how many carried a heading while the rover stood (truth under 1 cm/s), how many of
those headings were more than 90 degrees off, and how many headings were more than 90 degrees off in all (a rover's
firmware takes the first heading it is sent as its own).
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
from bench_tracking import FAMILY_SCENARIOS, family_clip  # noqa: E402
from tracking_runs import frame_of, plane_mapping  # noqa: E402

from edge.tracker_config import TrackerConfig  # noqa: E402
from edge.trackers.factory import build_tracker  # noqa: E402


def run(scenario: str, seed: int, frames: int | None) -> None:
    clip = family_clip(scenario, seed, frames)
    config = TrackerConfig(rovers=clip.rovers, method="particles", fps=clip.fps)  # type: ignore[attr-defined]
    tracker = build_tracker(config, plane_mapping(clip, "camera"), None)  # type: ignore[arg-type]
    poses = standing = standing_headed = standing_off = off = 0
    for i, image in enumerate(clip.frames):  # type: ignore[attr-defined]
        for e in tracker.process(frame_of(image, i, clip.fps)).estimates:  # type: ignore[attr-defined]
            _, _, theta, vx, vy, _ = clip.truth[i][e.rover_id]  # type: ignore[attr-defined]
            poses += 1
            still = math.hypot(vx, vy) < 1.0
            standing += still
            if e.theta_rad is None:
                continue
            wrong = abs(math.remainder(e.theta_rad - theta, math.tau)) > math.pi / 2
            off += wrong
            standing_headed += still
            standing_off += still and wrong
    print(
        f"| {scenario} | {seed} | {clip.camera_name} | {poses} | {standing} | {standing_headed} | {standing_off} | "  # type: ignore[attr-defined]
        f"{off} |",
        flush=True,
    )


def main() -> None:
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default=",".join(FAMILY_SCENARIOS))
    parser.add_argument("--seeds", default="1000")
    parser.add_argument("--frames", type=int, default=None)
    args = parser.parse_args()
    print(
        "| scenario | seed | camera | rover frames with a pose | standing | standing, with a heading | "
        "standing, heading over 90 deg off | any heading over 90 deg off |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for scenario in args.scenarios.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            run(scenario, seed, args.frames)


if __name__ == "__main__":
    main()
