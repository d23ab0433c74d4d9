"""The closed-loop bars judged on poses as published (what the rovers get), not on a simulator's ground truth: how
an end-to-end run of the twin, or of a real lab, is scored.

A pose here is the contract's pose v1 as a dict (``id``, ``frame``, ``t``, ``x``, ``y``); frames are the camera's
numbers, so "by frame 240 of the formation" counts camera frames from the first one after the command, whatever the
edge managed to track.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from edge.sim.metrics import Bar, converged_frame, formation_error


@dataclass(frozen=True)
class FormationScore:
    """``converged_frame``: from which frame after the command's the bar holds to the end (None: it does not hold at
    the end); ``frames``: frames in which every rover was seen; ``final_cm``: the last such frame's measure (line:
    worst displacement or spacing error; rendezvous: zone diameter; triangle: worst side error)."""

    kind: str
    converged_frame: int | None
    frames: int
    final_cm: float

    def holds_by(self, frame: int) -> bool:
        return self.converged_frame is not None and self.converged_frame <= frame


def score_formation(
    poses: Iterable[Mapping[str, Any]], ids: Sequence[str], kind: str, first_frame: int, frames: int
) -> FormationScore:
    """Judge frames ``first_frame`` .. ``first_frame + frames`` of ``poses`` by the closed-loop bar of ``kind``."""
    by_frame: dict[int, dict[str, tuple[float, float]]] = {}
    for p in poses:
        if first_frame <= p["frame"] <= first_frame + frames:
            by_frame.setdefault(int(p["frame"]), {})[str(p["id"])] = (float(p["x"]), float(p["y"]))
    numbers = sorted(k for k, seen in by_frame.items() if all(r in seen for r in ids))
    bar = Bar(kind)
    errors = [formation_error(bar, np.array([by_frame[k][r] for r in ids])) for k in numbers]
    index = converged_frame(errors)
    final = errors[-1] + (bar.zone_cm if kind == "rendezvous" else bar.tol_cm) if errors else math.nan
    return FormationScore(kind, None if index is None else numbers[index] - first_frame, len(numbers), final)


def largest_moves_cm(poses: Iterable[Mapping[str, Any]], ids: Sequence[str], t0: float, t1: float) -> dict[str, float]:
    """Each rover's largest distance from its first pose in [t0, t1] (pose time) to any later one there: how far it
    moved in that window (a standing rover: the tracker's noise)."""
    first: dict[str, tuple[float, float]] = {}
    moved = {rid: 0.0 for rid in ids}
    for p in poses:
        rid = str(p["id"])
        if rid not in moved or not t0 <= float(p["t"]) <= t1:
            continue
        x0, y0 = first.setdefault(rid, (float(p["x"]), float(p["y"])))
        moved[rid] = max(moved[rid], math.hypot(float(p["x"]) - x0, float(p["y"]) - y0))
    return moved
