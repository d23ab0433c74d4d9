#!/usr/bin/env python3
"""Each marker colour's bias over the whole camera family, pooled from ``bench_tracking.py family --detail`` outputs.

    .venv/bin/python benchmarks/family_colours.py OUT.md [OUT.md ...]

The family benchmark draws one camera per scenario and seed, and is run one seed per process; each output holds a
row per scenario, seed and colour (its "Every scenario, camera and colour" table). The issue's bar is on the
family: a colour's *mean* bias over the cameras it was seen through (each run one camera, weighted alike), at most
0.05 cm for every hue of the default palette and of the eight-hue palette. Printed per colour: the runs, that mean
(x, y and its length), and, for scale, the median and the largest single run's bias length (the per-run figure
the family table's "worst colour bias" column and its bars use). An output of ``--calibration both`` counts
its first table only (the camera's calibration). A file without that table is one line on stderr, exit 2.
"""

from __future__ import annotations

import math
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from edge.sim.scene import EIGHT_HUES  # noqa: E402  (after the sys.path line above)

BAR_CM = 0.05
PALETTES = tuple(dict.fromkeys(("red", "green", "blue", *(name for name, _ in EIGHT_HUES))))  # default, then eight
TABLE = "Every scenario, camera and colour:"


@dataclass(frozen=True)
class ColourRun:
    """One colour in one run (scenario, seed: one camera of the family): its bias on the floor, x and y (cm)."""

    scenario: str
    seed: int
    colour: str
    bias_x: float
    bias_y: float


def read_runs(path: Path) -> list[ColourRun]:
    """The per-colour rows of one family output; ValueError naming the file when it has none or one is malformed."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    try:
        start = lines.index(TABLE)
    except ValueError:
        raise ValueError(f"{path}: no '{TABLE}' table (run the family benchmark with --detail)") from None
    runs = []
    for number, line in enumerate(lines[start + 1 :], start + 2):
        if not line.startswith("|"):
            if runs:
                break
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0] in ("scenario", "---") or cells[0].startswith("---"):
            continue
        try:
            x, y = (float(v) for v in cells[6].split(","))
            runs.append(ColourRun(cells[0], int(cells[1]), cells[2], x, y))
        except (IndexError, ValueError):
            raise ValueError(f"{path}:{number}: not a row of the table: {line[:80]!r}") from None
    if not runs:
        raise ValueError(f"{path}: the '{TABLE}' table has no rows")
    return runs


def pooled(runs: list[ColourRun]) -> dict[str, dict[str, float]]:
    """Per colour: the runs, the mean bias over them (x, y, length), the median and largest single run's length."""
    out: dict[str, dict[str, float]] = {}
    for colour in dict.fromkeys(r.colour for r in runs):
        mine = [r for r in runs if r.colour == colour]
        x = statistics.fmean(r.bias_x for r in mine)
        y = statistics.fmean(r.bias_y for r in mine)
        lengths = [math.hypot(r.bias_x, r.bias_y) for r in mine]
        out[colour] = {
            "runs": len(mine),
            "x": x,
            "y": y,
            "mean": math.hypot(x, y),
            "median_run": statistics.median(lengths),
            "worst_run": max(lengths),
        }
    return out


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if argv else 2
    runs: list[ColourRun] = []
    for name in argv:
        try:
            runs += read_runs(Path(name))
        except (OSError, ValueError) as e:
            print(f"family_colours: {e}", file=sys.stderr)
            return 2
    cameras = {(r.scenario, r.seed) for r in runs}
    print(f"## Each colour's bias over the camera family ({len(cameras)} runs from {len(argv)} files)\n")
    print("| colour | runs | mean bias x, y cm | its length cm | median run cm | worst run cm | bar (<= 0.05) |")
    print("|---|---|---|---|---|---|---|")
    stats = pooled(runs)
    order = sorted(stats, key=lambda c: (PALETTES.index(c) if c in PALETTES else len(PALETTES), c))
    for colour in order:
        s = stats[colour]
        bar = ("ok" if s["mean"] <= BAR_CM else "missed") if colour in PALETTES else "(not in the palettes)"
        print(
            f"| {colour} | {s['runs']:.0f} | {s['x']:+.3f}, {s['y']:+.3f} | {s['mean']:.3f} | "
            f"{s['median_run']:.3f} | {s['worst_run']:.3f} | {bar} |"
        )
    missed = [c for c in order if c in PALETTES and stats[c]["mean"] > BAR_CM]
    print(f"\nPalette colours over the bar: {len(missed)} ({', '.join(missed) or 'none'})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
