"""The cost of looking for a marker's shaded part (``edge.shade``), per window and per clip.

    python benchmarks/bench_shade.py [--calls 3000] [--scenario lab] [--seed 1000] [--camera family|nominal]

Prints the time of one ``shaded_part`` call on a 40 x 60 px window with a marker whose corner the threshold cut
(it looks, and finds the corner), and of one where the mask already holds the marker's size (it returns at once);
then, tracking the clip, in how many windows it looked. One core (``cv2.setNumThreads(1)``), best of 5 repeats.
"""

from __future__ import annotations

import argparse
import sys
import timeit
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import edge.shade as shade

H, W = 40, 60
TOP, BOTTOM, LEFT, RIGHT = 10, 26, 12, 44


def _window() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Opponent chroma, luminance, the marker and its cut mask: a warm floor, a marker (relative saturation 0.8)
    with a triangle of 8 px at its top left corner in the shade (half its brightness, its colour kept)."""
    c1 = np.full((H, W), 8.0, np.float32)
    c2 = np.full((H, W), 16.0, np.float32)
    lum = np.full((H, W), 100.0, np.float32)
    marker = np.zeros((H, W), bool)
    marker[TOP:BOTTOM, LEFT:RIGHT] = True
    rows, cols = np.mgrid[0:H, 0:W]
    corner = marker & ((rows - TOP) + (cols - LEFT) < 8)
    c1[marker], c2[marker], lum[marker] = 120.0, 0.0, 150.0
    c1[corner], lum[corner] = 60.0, 75.0
    return c1, c2, lum, marker, marker & ~corner


def per_call(calls: int) -> tuple[float, float]:
    c1, c2, lum, marker, cut = _window()
    candidates = np.ones((H, W), bool)
    px = float(np.count_nonzero(marker))
    assert shade.shaded_part(c1, c2, lum, candidates, cut, px) is not None
    looks = min(timeit.repeat(lambda: shade.shaded_part(c1, c2, lum, candidates, cut, px), number=calls, repeat=5))
    quick = min(timeit.repeat(lambda: shade.shaded_part(c1, c2, lum, candidates, marker, px), number=calls, repeat=5))
    return looks / calls, quick / calls


def windows_looked(scenario: str, seed: int, camera: str) -> tuple[int, int, int]:
    """(windows, looked, found) over the clip, tracked with the default tracker."""
    import tracking_runs as runs

    from edge.tracker_config import TrackerConfig
    from edge.trackers.factory import build_tracker

    counts = [0, 0, 0]
    original = shade.shaded_part

    def counted(c1, c2, lum, candidates, mask, marker_px):
        counts[0] += 1
        counts[1] += int(np.count_nonzero(mask) < shade.SHADE_MISSING * marker_px)
        part = original(c1, c2, lum, candidates, mask, marker_px)
        counts[2] += part is not None
        return part

    shade.shaded_part = counted
    try:
        clip = runs.render_clip(scenario, seed, camera=camera)
        config, mapping = TrackerConfig(rovers=clip.rovers, fps=clip.fps), runs.plane_mapping(clip, "camera")
        tracker = build_tracker(config, mapping, None)  # type: ignore[arg-type]
        for i, image in enumerate(clip.frames):
            tracker.process(runs.frame_of(image, i, clip.fps))
    finally:
        shade.shaded_part = original
    return counts[0], counts[1], counts[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=3000)
    parser.add_argument("--scenario", default="lab")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--camera", choices=("family", "nominal"), default="family")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    looks, quick = per_call(args.calls)
    print(f"shaded_part on a {H} x {W} px window: {looks * 1e6:.0f} us when it looks, {quick * 1e6:.1f} us when not")
    for camera in dict.fromkeys((args.camera, "nominal")):
        n, looked, found = windows_looked(args.scenario, args.seed, camera)
        print(
            f"{args.scenario} {args.seed}, {camera} camera: looked in {looked} of {n} windows, found a part in {found}"
        )


if __name__ == "__main__":
    main()
