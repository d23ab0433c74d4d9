"""Write a synthetic calibration kit (the paper's lab, exact ground truth) to try `edge-ips calibrate` on.

    .venv/bin/python benchmarks/calibration_demo.py DIR [--seed 0] [--distortion]

DIR receives: points.csv (34 survey points at 13 cm, 0.5 px RMS noise, planned layout), check.csv (20 independent
check points) and check_targets.png (printed targets on them, for `calibrate check --refine-on`), targets.png (a
photo of printed 2x2 checker targets on the survey points, for `calibrate points --refine-on`), reference.png and
floor.png (a frame with 12 ArUco markers on the floor), markers.csv, and with --distortion a lens with barrel
distortion plus boards/board_NN.png (14 checkerboard photos, 9x6, 2.5 cm).
docs/calibration.md was made from this kit with seed 0.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.camera import paper_camera, save_camera
from edge.sim.targets import (
    aruco_floor_frame,
    check_points,
    checkerboard_views,
    survey_points,
    survey_target_frame,
    targets_apart,
    write_markers_csv,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--distortion", action="store_true", help="a lens with barrel distortion, plus boards")
    args = parser.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    camera = paper_camera((-0.12, 0.04, 0.0008, -0.0005, 0.0) if args.distortion else (0.0,) * 5)
    save_camera(camera, out / "camera.json")
    survey = survey_points(camera, rng=args.seed)
    survey.write_csv(out / "points.csv")
    cv2.imwrite(str(out / "targets.png"), survey_target_frame(camera, survey.xy_world_cm, rng=args.seed + 4))
    check = check_points(camera, rng=args.seed + 1)
    check.write_csv(out / "check.csv")
    apart = check.xy_world_cm[targets_apart(check.xy_world_cm)]  # two cards cannot lie on one spot
    cv2.imwrite(str(out / "check_targets.png"), survey_target_frame(camera, apart, rng=args.seed + 5))
    frame = aruco_floor_frame(camera, rng=args.seed + 2)
    cv2.imwrite(str(out / "floor.png"), frame.image)
    cv2.imwrite(str(out / "reference.png"), frame.image)
    write_markers_csv(out / "markers.csv", frame.markers)
    if args.distortion:
        checkerboard_views(camera, rng=args.seed + 3).write(out / "boards")
    print(f"wrote the calibration kit to {out} (camera.json holds the ground-truth camera)")


if __name__ == "__main__":
    main()
