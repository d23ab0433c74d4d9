"""What the calibration alone costs the tracking bars: a perfect tracker's error over the family's runs.

    .venv/bin/python benchmarks/bench_calibration_floor.py                       # family runs, 0.5 px clicks
    .venv/bin/python benchmarks/bench_calibration_floor.py --noise 0.5,0.25,0.1 --surveys 2 --refine

Issue 15's bars (per run: mean <= 0.15 cm, p95 <= 0.4 cm, each colour's bias <= 0.05 cm) are to hold "with
`calibrate points` from 34 noisy points as well as with the exact camera". A calibration's error is a fixed
field over the floor: every frame of a rover at a place is mapped through the same error, so over a run it adds to
each rover's bias, not only to its scatter. Here each family run's rovers follow their paths exactly (the truth
projected through the scene's camera at the markers' height, i.e. a tracker without error) and are mapped back
through the calibration ``bench_tracking.py family --calibration points`` uses (34 points on the G-optimal 30 cm
grid, clicked with ``--noise`` px RMS radial error, the lens intrinsics given where the camera has distortion); the
runs' mean, p95 and each rover's bias are then the calibration's share of the bars. ``--surveys K`` draws K more
surveys per run (other click noise) so the figures are not one survey's luck. ``--refine``: each noise level also
with the clicks moved onto printed targets in a rendered photo of them (``calibrate points --refine-on``,
``bench_tracking.py family --calibration targets``).

Ground truth only: nothing is rendered but the targets' photo, so the whole table takes a few minutes.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from tracking_runs import survey_calibration

from edge.sim.scenarios import build

SCENARIOS = ("lab", "lens", "occlusion", "sun", "crowd8", "drift", "cross", "crowd", "daylight")
SEEDS = (1000, 4321, 14641, 16661)
BARS = {"mean": 0.15, "p95": 0.4, "bias": 0.05}  # bench_tracking.BARS, the issue's


@dataclass(frozen=True)
class Paths:
    """A run's rovers' true marker centres over its frames (in the image), the camera and the plane's height."""

    camera: object
    height_cm: float
    xy: dict[str, np.ndarray]  # rover id -> (frames, 2) world cm, the frames where its centre is in the image


def run_paths(name: str, seed: int) -> Paths:
    """The family run ``name`` for ``seed`` (``crowd8``: the crowd with eight rovers), its truth only."""
    scenario, rovers = ("crowd", 8) if name == "crowd8" else (name, None)
    setup = build(scenario, seed, rovers, None, "plain", "family")
    world, camera, h = setup.world(), setup.camera, setup.marker_height_cm
    w, hgt = camera.width_px, camera.height_px  # type: ignore[attr-defined]
    per: dict[str, list[tuple[float, float]]] = {}
    for i in range(setup.frames):
        for r in world.state_at(i / setup.fps).rovers:
            per.setdefault(r.rover_id, []).append((r.x_cm, r.y_cm))
    xy = {}
    for rid, pts in per.items():
        p = np.asarray(pts, float)
        uv = camera.project(np.column_stack([p, np.full(len(p), h)]))  # type: ignore[attr-defined]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < hgt)
        xy[rid] = p[inside]
    return Paths(camera, h, xy)


def floor_errors(paths: Paths, calibration: Any) -> dict[str, np.ndarray]:
    """Rover id -> (frames, 2) the calibration's error (mapped minus true, cm) along the rover's path."""
    out = {}
    for rid, p in paths.xy.items():
        uv = paths.camera.project(np.column_stack([p, np.full(len(p), paths.height_cm)]))  # type: ignore[attr-defined]
        out[rid] = calibration.pixel_to_world(uv) - p
    return out


def run_figures(errors: dict[str, np.ndarray]) -> tuple[float, float, float]:
    """A run's mean and p95 error over every rover's frames, and its worst rover's bias (cm)."""
    dist = np.concatenate([np.hypot(e[:, 0], e[:, 1]) for e in errors.values() if len(e)])
    worst = max(float(np.hypot(*e.mean(axis=0))) for e in errors.values() if len(e))
    return float(dist.mean()), float(np.percentile(dist, 95)), worst


def refined_note(used: list[float]) -> str:
    return f" refined on targets: {np.mean(used):.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--seeds", default=",".join(str(s) for s in SEEDS))
    ap.add_argument("--noise", default="0.5", help="click noise, px RMS radial (comma-separated: each in turn)")
    ap.add_argument("--surveys", type=int, default=0, help="more surveys per run, other click noise")
    ap.add_argument("--refine", action="store_true", help="each noise also with the clicks refined on targets")
    args = ap.parse_args()
    names = [s for s in args.scenarios.split(",") if s]
    seeds = [int(s) for s in args.seeds.split(",") if s]
    noises = [float(v) for v in args.noise.split(",") if v]
    print(f"# edge-ips: the calibration's share of the tracking bars, {datetime.now(UTC):%Y-%m-%d %H:%M} UTC\n")
    print(f"family runs {','.join(names)} x seeds {','.join(map(str, seeds))}; a tracker without error; 34 points")
    print(f"per survey; {1 + args.surveys} survey(s) per run (the first is `family --calibration points`' own);")
    print("refined:", end=" ")
    print("the clicks moved onto the X-corners of printed targets in a rendered photo (their RMS error after, px)\n")
    paths = {(n, s): run_paths(n, s) for n in names for s in seeds}
    print(
        "| clicks px RMS | runs x surveys | mean cm: median / worst run | p95 cm: median / worst | runs over the mean "
        "/ p95 bar | rovers' bias cm: median / p90 / worst | rovers over the 0.05 cm bias bar | runs with one over it |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for noise, refine in [(n, r) for n in noises for r in ((False, True) if args.refine else (False,))]:
        means, p95s, biases, runs_over, used = [], [], [], 0, []
        for (_, seed), p in paths.items():
            for k in range(1 + args.surveys):
                rng = 1000 + seed if k == 0 else 10_000 * k + seed
                calibration, rms_px = survey_calibration(p.camera, p.height_cm, rng, noise, refine)
                used.append(rms_px)
                errors = floor_errors(p, calibration)
                mean, p95, worst = run_figures(errors)
                means.append(mean)
                p95s.append(p95)
                rover_bias = [float(np.hypot(*e.mean(axis=0))) for e in errors.values() if len(e)]
                biases.extend(rover_bias)
                runs_over += worst > BARS["bias"]
        m, q, b = np.array(means), np.array(p95s), np.array(biases)
        label = f"{noise:g}{refined_note(used) if refine else ''}"
        print(
            f"| {label} | {len(m)} | {np.median(m):.3f} / {m.max():.3f} | {np.median(q):.3f} / {q.max():.3f} | "
            f"{int((m > BARS['mean']).sum())} / {int((q > BARS['p95']).sum())} | "
            f"{np.median(b):.3f} / {np.percentile(b, 90):.3f} / {b.max():.3f} | "
            f"{int((b > BARS['bias']).sum())} of {len(b)} | {runs_over} of {len(m)} |"
        )


if __name__ == "__main__":
    main()
