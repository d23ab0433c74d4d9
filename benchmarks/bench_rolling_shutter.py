"""What a rolling shutter costs the tracker, and what ``[tracker] line_time_us`` gives back.

    .venv/bin/python benchmarks/bench_rolling_shutter.py              # lab, cross, crowd; seeds 0, 1
    .venv/bin/python benchmarks/bench_rolling_shutter.py --scenarios lab --seeds 0 --line-us 44.4,30
    .venv/bin/python benchmarks/bench_rolling_shutter.py --measure    # the line time from flicker bands

A webcam's sensor exposes its rows one after the other: row ``v`` ``v * line_time`` after row 0 (about 44 us a row
for 720 rows read out in a 30 fps frame). A rover moving at 30 cm/s near the bottom of the frame is seen about 1 cm
from where it was when the frame's first row was exposed. Each scenario is rendered by the simulator twice, with a
global shutter and with a rolling one (``edge.sim.effects.RollingShutter``, truth at the frame's time: row 0's), and
tracked (particles, the exact camera) with the setting off (0) and at the camera's line time. Per run: mean, p95 and
max error (cm) over every rover and frame, and the mean and p95 error of moving rovers (over 5 cm/s) along their
direction of motion (cm: + ahead of the truth). The last row of each scenario is the cost of the setting on a camera
without a rolling shutter.

``--measure``: what ``edge-ips calibrate line-time`` (``edge.line_time``) reads off the simulator's rolling flicker
bands, per line time, mains frequency, frame rate, exposure and ripple.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from tracking_runs import Clip, frame_of, plane_mapping, summary

from edge.tracker_config import TrackerConfig
from edge.trackers.factory import build_tracker

MOVING_CM_S = 5.0


def track(clip: Clip, line_time_us: float) -> tuple[dict[str, float], np.ndarray]:
    """Track ``clip`` with the setting; the summary over every rover and the along-motion errors of moving ones."""
    from tracking_runs import Score, _score_frame

    config = TrackerConfig(rovers=clip.rovers, method="particles", fps=clip.fps, line_time_us=line_time_us)  # type: ignore[arg-type]
    tracker = build_tracker(config, plane_mapping(clip, "camera"))  # type: ignore[arg-type]
    score = Score()
    along: list[float] = []
    for i, image in enumerate(clip.frames):
        result = tracker.process(frame_of(image, i, clip.fps))
        got = {e.rover_id: e for e in result.estimates}
        _score_frame(score, clip.truth[i], got)
        for rid, (x, y, _th, vx, vy, vis) in clip.truth[i].items():
            e = got.get(rid)
            speed = math.hypot(vx, vy)
            if e is None or vis < 0.99 or speed < MOVING_CM_S:
                continue
            along.append(((e.x_cm - x) * vx + (e.y_cm - y) * vy) / speed)
    return summary(score.total()), np.asarray(along)


def measure_line_times() -> None:
    """``edge.line_time`` on simulated frames: the lab floor through an MJPG camera (4:2:0 q70, noise), a rover
    driving through, lamps rippling by ``modulation`` at a manual exposure; 30 frames each."""
    from edge.camera import paper_camera
    from edge.line_time import NoFlicker, line_time_from_flicker
    from edge.sim.effects import Compression, Effects, Exposure, Flicker
    from edge.sim.render import Renderer
    from edge.sim.scene import Scene, fleet_looks
    from edge.sim.world import RoverState, WorldState

    print("| line time us | mains Hz | fps | exposure ms | ripple | measured us | error % | band contrast % | time s |")
    print("|---|---|---|---|---|---|---|---|---|")
    cases = [
        (44.4, 50.0, 30.0, 0.5, 0.3),
        (44.4, 50.0, 30.0, 5.0, 0.3),
        (44.4, 50.0, 30.0, 0.5, 0.05),
        (30.0, 50.0, 30.0, 0.5, 0.3),
        (20.0, 50.0, 30.0, 0.5, 0.3),
        (40.0, 60.0, 25.0, 0.5, 0.3),
        (44.4, 60.0, 30.0, 0.5, 0.3),
        (44.4, 50.0, 30.0, 10.0, 0.3),
    ]
    for line_us, mains, fps, exposure_ms, ripple in cases:
        effects = Effects(
            exposure=Exposure(exposure_s=exposure_ms * 1e-3),
            flicker=Flicker(mains_hz=mains, modulation=ripple, line_time_s=line_us * 1e-6),
            compression=Compression(70, "4:2:0"),
        )
        renderer = Renderer(paper_camera(), Scene(fleet_looks(1)), effects, fps=fps)
        rid = renderer.scene.rovers[0].rover_id
        frames = [
            renderer.render(WorldState(i / fps, (RoverState(rid, 100.0 + 3 * i, 250.0, 0.0, 90.0, 0.0, 90.0),)), i)
            for i in range(30)
        ]
        t0 = time.perf_counter()
        try:
            r = line_time_from_flicker(frames, mains, fps)
            cells = f"{r.line_time_us:.2f} | {100 * (r.line_time_us / line_us - 1):+.2f} | {100 * r.contrast:.2f}"
        except NoFlicker as exc:
            cells = f"refused: {str(exc).split(':')[0]} | | "
        print(
            f"| {line_us:g} | {mains:g} | {fps:g} | {exposure_ms:g} | {ripple:g} | {cells} "
            f"| {time.perf_counter() - t0:.2f} |",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default="lab,cross,crowd")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--line-us", default="44.4", help="the rolling shutter's line times to render, us")
    parser.add_argument("--measure", action="store_true", help="only: the line time measured from flicker bands")
    args = parser.parse_args()
    if args.measure:
        print(f"# edge-ips line time from flicker, {time.strftime('%Y-%m-%d %H:%M')}, {platform.node()}\n")
        measure_line_times()
        return
    from tracking_runs import render_clip

    print(f"# edge-ips rolling shutter, {time.strftime('%Y-%m-%d %H:%M')}, {platform.node()}, {platform.machine()}\n")
    print(
        "| scenario, seed | camera's shutter | tracker's line_time_us | mean / p95 / max cm "
        "| along motion: mean / p95 |cm| |"
    )
    print("|---|---|---|---|---|")
    for name in args.scenarios.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            runs: list[tuple[str, Clip, float]] = []
            global_clip = render_clip(name, seed)
            runs.append(("global", global_clip, 0.0))
            for line_us in (float(v) for v in args.line_us.split(",")):
                rolling = render_clip(name, seed, line_time_s=line_us * 1e-6)
                runs += [(f"rolling {line_us:g} us", rolling, 0.0), (f"rolling {line_us:g} us", rolling, line_us)]
            runs.append(("global", global_clip, float(args.line_us.split(",")[0])))
            for shutter, clip, setting in runs:
                s, along = track(clip, setting)
                a = f"{along.mean():+.3f} / {np.percentile(np.abs(along), 95):.3f}" if along.size else "-"
                print(
                    f"| {name} {seed} | {shutter} | {setting:g} | {s['mean']:.3f} / {s['p95']:.3f} / {s['max']:.3f} "
                    f"| {a} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
