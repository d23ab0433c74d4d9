"""Colour enrolment (``edge.enroll``) over the camera family: does every rover get enrolled, at its place, at its size?

    python benchmarks/bench_enrolment.py [--seeds 0-19] [--palette eight|three|two-tone] [--floors wood,tiles]

For each seed and floor: a still of the paper's lab seen by a webcam drawn from the family (``edge.sim.cameras``:
stream, optics, colour response, white balance, processor) with the rovers' bodies drawn too (black, dark grey or
white, 8-20 cm tall), the rovers spread over two rows, and the empty floor. The frame and the floor are enrolled
(``eight``: the eight-hue palette with its ids; ``three``: red, green, blue named by hue; ``two-tone``: red, green,
blue with a light front). Each enrolled marker is matched to the rover it stands nearest. Prints, per floor, the
labs enrolled whole (every rover once, within 2 cm of its place, its id on its own marker when ids are given, no
front on a one-colour marker) and those refused, the worst centre error, the enrolled areas as a share of the
marker's (1st / 50th / 99th percentile, over the labs not refused), the markers named otherwise than their rover
(named by hue, a blue marker the camera sees as azure is "azure") and, for two-tone markers, how many front
fractions on dark bodies came within 0.08 of the true 0.3 and how many markers were enrolled without a front and
named so in a warning (for one-colour markers, how many were given a front and how many were named as two-tone
markers without their front: none should be); then each lab not whole. The enrolment's constants were set on
seeds 0-19 (eight, two-tone) and 0-29 (three): run other seeds for held-out figures.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge.calibration.exact import exact_calibration
from edge.camera import paper_camera
from edge.enroll import enroll
from edge.errors import EnrollmentError
from edge.sim.cameras import draw_family
from edge.sim.render import Renderer
from edge.sim.scene import FLOORS, RoverLook, Scene, fleet_looks, marker_albedo_for_hue
from edge.sim.setup import lab_effects
from edge.sim.world import RoverState, WorldState

HUES = (("red", 0), ("orange", 30), ("yellow", 60), ("green", 120), ("cyan", 180), ("blue", 240), ("purple", 270),
        ("magenta", 300))  # fmt: skip


def palette(name: str) -> tuple[RoverLook, ...]:
    if name == "eight":
        return tuple(RoverLook(n, marker_albedo_for_hue(h)) for n, h in HUES)
    looks = fleet_looks(3)
    return tuple(replace(look, heading="two_tone") for look in looks) if name == "two-tone" else looks


def spread(n: int) -> list[tuple[float, float, float]]:
    cols = math.ceil(n / 2)
    return [
        (60.0 + 270.0 * (k % cols) / max(cols - 1, 1), 130.0 + 260.0 * (k // cols), 0.4 * k - 1.0) for k in range(n)
    ]


@dataclass(frozen=True)
class Lab:
    """One lab's enrolment: ``whole`` (every rover once, within 2 cm, ids on their own markers, no front on a
    one-colour marker), ``refused`` (an EnrollmentError), the worst centre error (cm), the areas over the
    marker's, (front fraction, dark body) per marker, the markers named otherwise than their rover, why not whole."""

    whole: bool
    refused: bool
    worst_cm: float
    areas: list[float]
    fronts: list[tuple[float | None, bool]]
    renamed: int
    front_missing: int
    why: str


def one_lab(seed: int, floor: str, name: str) -> Lab:
    """Enrol one drawn lab."""
    drawn, looks = draw_family("enrol", seed, palette(name))
    camera = paper_camera()
    renderer = Renderer(
        camera,
        Scene(rovers=looks, floor=FLOORS[floor]),
        drawn.apply(lab_effects(np.random.default_rng(seed))),
        seed=seed,
    )
    calibration = exact_calibration(camera, looks[0].body_height_cm)
    poses = spread(len(looks))
    states = tuple(RoverState(look.rover_id, x, y, th, 0.0, 0.0) for look, (x, y, th) in zip(looks, poses, strict=True))
    frame = renderer.render(WorldState(5 / 30.0, states), 5)
    ids = [look.rover_id for look in looks] if name == "eight" else None
    try:
        result = enroll(frame, renderer.background(5), calibration, ids=ids)
    except EnrollmentError as exc:
        return Lab(False, True, math.inf, [], [], 0, 0, f"{seed} {floor} {drawn.name}: {exc}")
    errors, fronts, matched, renamed = [], [], [], 0
    for m in result.markers:  # each marker to the rover it stands on
        k = min(range(len(poses)), key=lambda k: math.hypot(m.xy_cm[0] - poses[k][0], m.xy_cm[1] - poses[k][1]))
        matched.append(k)
        errors.append(math.hypot(m.xy_cm[0] - poses[k][0], m.xy_cm[1] - poses[k][1]))
        fronts.append((m.front_fraction, looks[k].body_bgr[0] < 0.5))
        renamed += m.rover_id != looks[k].rover_id
    worst = max(errors)
    false_fronts = name != "two-tone" and any(front is not None for front, _ in fronts)
    swapped = ids is not None and renamed > 0  # an id given to another rover's marker; by hue, "azure" is a name
    ok = sorted(matched) == list(range(len(looks))) and worst <= 2.0 and not false_fronts and not swapped
    areas = [m.area_cm2 / (looks[0].marker_length_cm * looks[0].marker_width_cm) for m in result.markers]
    names = ", ".join(m.rover_id for m in result.markers)
    why = "" if ok else f"{seed} {floor} {drawn.name}: {names}; worst {worst:.1f} cm"
    missing = sum("no light front was found" in warning for warning in result.warnings)
    return Lab(ok, False, worst, areas, fronts, renamed, missing, why)


def seeds_of(text: str) -> list[int]:
    if "-" in text:
        lo, hi = (int(v) for v in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(v) for v in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0-19")
    parser.add_argument("--palette", choices=("eight", "three", "two-tone"), default="eight")
    parser.add_argument("--floors", default="wood,tiles")
    args = parser.parse_args()
    failures = []
    for floor in args.floors.split(","):
        labs = [one_lab(seed, floor, args.palette) for seed in seeds_of(args.seeds)]
        failures += [lab.why for lab in labs if lab.why]
        areas = [a for lab in labs for a in lab.areas]
        fronts = [f for lab in labs for f in lab.fronts]
        worst = max((lab.worst_cm for lab in labs if not lab.refused), default=math.nan)
        share = np.percentile(areas, [1, 50, 99]) if areas else np.array([math.nan] * 3)
        line = (
            f"{floor:6s} {args.palette}: {sum(lab.whole for lab in labs)} of {len(labs)} labs whole, "
            f"{sum(lab.refused for lab in labs)} refused; worst centre {worst:.2f} cm (labs not refused), "
            f"area / marker p1 {share[0]:.2f} p50 {share[1]:.2f} p99 {share[2]:.2f}; markers named otherwise than "
            f"their rover: {sum(lab.renamed for lab in labs)}"
        )
        said = sum(lab.front_missing for lab in labs)
        if args.palette == "two-tone":
            dark = [fr for fr, is_dark in fronts if is_dark]
            near = sum(fr is not None and abs(fr - 0.3) <= 0.08 for fr in dark)
            line += f"; fronts on dark bodies within 0.08 of 0.3: {near} of {len(dark)}"
            line += f"; markers enrolled without a front: {sum(fr is None for fr, _ in fronts)}, named so: {said}"
        else:
            line += f"; one-colour markers given a front: {sum(fr is not None for fr, _ in fronts)}"
            line += f"; named as a two-tone marker without its front: {said} of {len(fronts)}"
        print(line, flush=True)
    for why in failures:
        print("  failed:", why)


if __name__ == "__main__":
    main()
