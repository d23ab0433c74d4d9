"""The tracker's per-frame work in machine instructions (valgrind's callgrind), which a shared machine's load and a
virtual machine's changing speed do not move, unlike milliseconds.

    python benchmarks/bench_instructions.py [--frames 150] [--seed 0] [--baseline OTHER_CHECKOUT]

The ``lab`` clip (3 rovers, as ``bench_tracking.py stages``) is rendered once; each checkout then tracks it in a
process under callgrind with counting off for its first 10 frames (the plane grid's and pixel tables' one-time
build, the rovers' acquisition) and on for the rest, which ends the process (``os._exit``: the interpreter's
shutdown is not a frame's work). Prints instructions per tracked frame and, with ``--baseline``, their ratio.
Needs Debian's ``valgrind`` (``callgrind_control`` with it); a run takes a few minutes.
"""

from __future__ import annotations

import argparse
import os
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WARM_UP = 10  # frames tracked before counting starts


def count(root: str, clip_path: Path, frames: int, out_dir: Path) -> float:
    """Instructions per frame of checkout ``root`` tracking ``frames`` frames after the warm-up."""
    out = out_dir / f"callgrind.{abs(hash(root))}.out"
    cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}"]
    cmd += [sys.executable, __file__, "_worker", root, str(clip_path), str(frames)]
    env = {**os.environ, "PYTHONPATH": root, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    log = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stderr
    collected = re.search(r"Collected : (\d+)", log)
    if collected is None:
        raise RuntimeError(f"callgrind gave no count:\n{log[-2000:]}")
    return int(collected.group(1)) / frames


def worker(root: str, clip_path: str, frames: int) -> None:
    """Track the pickled clip with ``root``'s ``edge``; counting on (``callgrind_control``) after the warm-up."""
    sys.path.insert(0, root)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import cv2

    cv2.setNumThreads(1)
    from tracking_runs import frame_of

    from edge.tracker_config import TrackerConfig
    from edge.trackers.base import CameraPlaneMapping
    from edge.trackers.factory import build_tracker

    clip = pickle.loads(Path(clip_path).read_bytes())
    config = TrackerConfig(rovers=clip.rovers, method="particles", fps=clip.fps)
    tracker = build_tracker(config, CameraPlaneMapping(clip.camera, clip.height_cm), None)
    todo = [frame_of(image, i, clip.fps) for i, image in enumerate(clip.frames[: WARM_UP + frames])]
    for frame in todo[:WARM_UP]:
        tracker.process(frame)
    switch = subprocess.Popen(["callgrind_control", "--instr=on", str(os.getpid())], stdout=subprocess.DEVNULL)
    while switch.poll() is None:  # counting starts once callgrind has answered
        time.sleep(0.001)
    for frame in todo[WARM_UP:]:
        tracker.process(frame)
    os._exit(0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=140, help="frames counted (after 10 warm-up frames)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--baseline", help="another checkout of the repository to count as well")
    args = parser.parse_args()
    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        sys.exit("valgrind is not installed (Debian: apt-get install valgrind)")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from tracking_runs import render_clip

    clip = render_clip("lab", args.seed, WARM_UP + args.frames)
    roots = {"this checkout": str(Path(__file__).resolve().parent.parent)}
    if args.baseline:
        roots["baseline"] = str(Path(args.baseline).resolve())
    with tempfile.TemporaryDirectory() as tmp:
        clip_path = Path(tmp) / "clip.pkl"
        clip_path.write_bytes(pickle.dumps(clip))
        counts = {name: count(root, clip_path, args.frames, Path(tmp)) for name, root in roots.items()}
    print(f"## Instructions per frame (callgrind), lab seed {args.seed}, 3 rovers, {args.frames} frames counted\n")
    print("| checkout | path | million instructions per frame |")
    print("|---|---|---|")
    for name, root in roots.items():
        print(f"| {name} | {root} | {counts[name] / 1e6:.2f} |")
    if args.baseline:
        print(f"\nthis / baseline: {counts['this checkout'] / counts['baseline']:.3f}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "_worker":
        worker(sys.argv[2], sys.argv[3], int(sys.argv[4]))
    else:
        main()
