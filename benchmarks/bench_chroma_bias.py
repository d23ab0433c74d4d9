"""Where the colour-dependent bias of the marker centre comes from: single frames of one marker at known poses,
rendered through the simulator's camera with one JPEG chroma sampling and quality at a time.

    python benchmarks/bench_chroma_bias.py [--poses N] [--seed S] [--palette default|eight]

The centre is the tracker's default one (``edge.coverage.coverage_weights``: the linear-light coverage, its area
centroid on the plane by ``world_blob``); the marker's interior mask is the truth's (the pixels whose centre lies
on the marker), so only the sub-pixel edge is measured. Each row: one chroma sampling and quality over every body
(black, dark grey, white, with 1 cm of the body's top around the marker), blur (0.5 and 1.2 px) and marker colour,
``--poses`` random poses each over the whole floor (seed ``--seed``): the mean error (x, y) over all of them and the
worst per-colour mean |(x, y)| (the bias bar: 0.05 cm). ``none`` is the uncompressed frame; ``q100`` JPEG with
the least quantisation (the chroma subsampling alone); lower qualities add the quantisation of the chroma.
No noise, no motion, no automatic exposure: the bias, not the scatter.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

if importlib.util.find_spec("edge") is None:  # run from a checkout without the package installed
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.camera import paper_camera
from edge.coverage import coverage_weights
from edge.sim.effects import Compression, Effects, Optics
from edge.sim.render import Renderer
from edge.sim.scene import BLUE_BGR, EIGHT_HUES, GREEN_BGR, RED_BGR, RoverLook, Scene, marker_albedo_for_hue
from edge.sim.world import RoverState, WorldState
from edge.trackers.base import CameraPlaneMapping, PlaneGrid
from edge.trackers.plane import world_blob

BODIES = {"black": (0.035, 0.034, 0.032), "dark grey": (0.12, 0.12, 0.12), "white": (0.8, 0.8, 0.8)}
BLURS_PX = (0.5, 1.2)
STREAMS = (
    ("none", None),
    ("4:4:4", 100),
    ("4:4:4", 90),
    ("4:4:4", 70),
    ("4:2:2", 100),
    ("4:2:2", 90),
    ("4:2:2", 70),
    ("4:2:0", 100),
    ("4:2:0", 90),
    ("4:2:0", 70),
)
MARKER_CM = (21.5, 16.8)
MARGIN_CM = 1.0


def palette(name: str) -> dict[str, tuple[float, float, float]]:
    if name == "default":
        return {"red": RED_BGR, "green": GREEN_BGR, "blue": BLUE_BGR}
    return {hue_name: marker_albedo_for_hue(hue) for hue_name, hue in EIGHT_HUES}


def centre_error_cm(image: np.ndarray, pose: tuple[float, float, float], grid: PlaneGrid) -> tuple[float, float]:
    """(x, y) error of the coverage centroid of the marker at ``pose`` in ``image``."""
    x, y, th = pose
    uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
    local = grid.at(*uv)
    assert local is not None
    _, _, su, sv = local.pixel_of(x, y)
    reach = 18.0
    x0, y0 = int(uv[0] - reach * su) - 6, int(uv[1] - reach * sv) - 6
    x1, y1 = int(uv[0] + reach * su) + 7, int(uv[1] + reach * sv) + 7
    xs, ys = grid.x_cm[y0:y1, x0:x1], grid.y_cm[y0:y1, x0:x1]
    along = (xs - x) * math.cos(th) + (ys - y) * math.sin(th)
    across = (ys - y) * math.cos(th) - (xs - x) * math.sin(th)
    core = (np.abs(along) < MARKER_CM[0] / 2) & (np.abs(across) < MARKER_CM[1] / 2)
    weights = coverage_weights(np.ascontiguousarray(image[y0:y1, x0:x1]), core, 2, pure=core)
    blob = world_blob(weights, (x0, y0), grid)
    assert blob is not None
    return blob.x_cm - x, blob.y_cm - y


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--poses", type=int, default=4, help="random poses per body, blur and colour")
    parser.add_argument("--seed", type=int, default=2000)
    parser.add_argument("--palette", choices=("default", "eight"), default="default")
    args = parser.parse_args()
    grid = PlaneGrid(CameraPlaneMapping(paper_camera()), (1280, 720))
    colours = palette(args.palette)
    rng = np.random.default_rng(args.seed)
    poses = [
        (float(rng.uniform(40, 380)), float(rng.uniform(60, 520)), float(rng.uniform(-math.pi, math.pi)))
        for _ in range(args.poses)
    ]
    print(f"# edge-ips chroma bias on static poses, {time.strftime('%Y-%m-%d %H:%M')}\n")
    print(f"{args.poses} poses (seed {args.seed}) x bodies {', '.join(BODIES)} x blur {BLURS_PX} px x {args.palette}")
    print("palette; exact interior mask; the default centre (linear-light coverage centroid).\n")
    print(
        "| stream | bias x, y cm (all) | mean error cm | worst colour bias cm | black body bias y | white body bias y |"
    )
    print("|---|---|---|---|---|---|")
    for chroma, quality in STREAMS:
        errors: dict[tuple[str, str], list[tuple[float, float]]] = {}
        for body, blur, colour in itertools.product(BODIES, BLURS_PX, colours):
            look = RoverLook(
                "r",
                colours[colour],
                body_bgr=BODIES[body],
                body_length_cm=MARKER_CM[0] + 2 * MARGIN_CM,
                body_width_cm=MARKER_CM[1] + 2 * MARGIN_CM,
            )
            compression = None if quality is None else Compression(quality, chroma)
            effects = Effects(
                auto_exposure=None, noise=None, motion_blur=False, optics=Optics(blur), compression=compression
            )
            renderer = Renderer(paper_camera(), Scene((look,)), effects)
            for pose in poses:
                image = renderer.render(WorldState(0.0, (RoverState("r", *pose, 0.0, 0.0, 0.0),)), 0)
                errors.setdefault((body, colour), []).append(centre_error_cm(image, pose, grid))
        every = np.array([e for v in errors.values() for e in v])
        per_colour = {
            c: np.array([e for (_, cc), v in errors.items() if cc == c for e in v]).mean(axis=0) for c in colours
        }
        worst = max(per_colour, key=lambda c: float(np.hypot(*per_colour[c])))
        by_body = {b: np.array([e for (bb, _), v in errors.items() if bb == b for e in v]).mean(axis=0) for b in BODIES}
        bias = every.mean(axis=0)
        name = "none" if quality is None else f"{chroma} q{quality}"
        print(
            f"| {name} | {bias[0]:+.3f}, {bias[1]:+.3f} | {float(np.hypot(*every.T).mean()):.3f} | "
            f"{float(np.hypot(*per_colour[worst])):.3f} ({worst}) | {by_body['black'][1]:+.3f} | "
            f"{by_body['white'][1]:+.3f} |"
        )


if __name__ == "__main__":
    main()
