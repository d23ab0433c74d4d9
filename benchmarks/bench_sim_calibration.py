"""Calibration measured on the simulator's scenes: files written by ``edge-ips sim render``, fitted
by ``edge-ips calibrate`` exactly as a person would, true error over the whole working area against the camera model
that rendered the scene.

    .venv/bin/python benchmarks/bench_sim_calibration.py [--seeds 20] [--lens-seeds 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from click.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.calibration import load_calibration
from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM, MARKER_HEIGHT_CM, load_camera
from edge.cli import main as cli


def run(*args: str) -> None:
    result = CliRunner().invoke(cli, list(args))
    if result.exit_code != 0:
        raise SystemExit(f"edge-ips {' '.join(args)} failed: {result.output}")


def true_error(run_dir: Path, calibration: Path) -> np.ndarray:
    camera = load_camera(run_dir / "camera.json")
    cal = load_calibration(calibration, expected_size=(camera.width_px, camera.height_px))
    gx, gy = np.meshgrid(np.linspace(0, AREA_WIDTH_CM, 60), np.linspace(0, AREA_LENGTH_CM, 80))
    world = np.column_stack([gx.ravel(), gy.ravel()])
    uv = camera.project(np.column_stack([world, np.full(len(world), MARKER_HEIGHT_CM)]))
    return np.hypot(*(cal.pixel_to_world(uv) - world).T)


def one(scenario: str, seed: int, root: Path) -> tuple[float, float]:
    d = root / f"{scenario}{seed}"
    lens = scenario == "lens"
    run("sim", "render", scenario, "--out", str(d), "--frames", "1", "--seed", str(seed), *(["--kit"] if lens else []))
    extra: list[str] = []
    if lens:
        boards = sorted(str(p) for p in (d / "boards").glob("board_*.png"))
        run("calibrate", "intrinsics", *boards, "--board", "9x6", "--square", "2.5", "--out", str(d / "intr.json"))
        extra = ["--intrinsics", str(d / "intr.json")]
    out = d / "cal.json"
    area = f"{AREA_WIDTH_CM}x{AREA_LENGTH_CM}"
    run("calibrate", "points", str(d / "points.csv"), "--out", str(out), "--image", str(d / "background.png"),
        "--area", area, *extra)  # fmt: skip
    err = true_error(d, out)
    return float(err.mean()), float(err.max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--lens-seeds", type=int, default=5)
    args = parser.parse_args()
    t0 = time.time()
    print(f"# calibration from simulated scenes, {time.strftime('%Y-%m-%d %H:%M')}")
    print(
        "| scenario | seeds | mean error cm (mean / worst seed) | max error cm (median / p90 / worst seed) "
        "| seeds with max <= 0.6 cm |"
    )
    print("|---|---:|---|---|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for scenario, n in (("lab", args.seeds), ("lens", args.lens_seeds)):
            stats = np.array([one(scenario, seed, Path(tmp)) for seed in range(n)])
            means, maxes = stats[:, 0], stats[:, 1]
            print(
                f"| {scenario} | {n} | {means.mean():.3f} / {means.max():.3f} | {np.median(maxes):.3f} / "
                f"{np.percentile(maxes, 90):.3f} / {maxes.max():.3f} | {np.mean(maxes <= 0.6) * 100:.0f}% |",
                flush=True,
            )
    print(f"\n({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
