"""Synthetic boards for the fusion tests: rovers on known paths, each board a view of the floor with its own
clock, exposure phase, noise and calibration bias, the covariances a board would attach. Independent of the
simulator and of the tracker on purpose: the fusion core is tested on detections whose truth is exact."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from edge.fusion.detections import Detection, Detections

Path2D = Callable[[float], tuple[float, float]]
MARKER_RADIUS_CM = 13.6


@dataclass(frozen=True)
class Board:
    """A camera board seeing ``x0 <= x <= x1``, ``y0 <= y <= y1`` (cm) of the floor.

    ``clock_offset_s``: its clock minus the true time; ``phase_s``: its frames are exposed at ``k / fps + phase``
    (true time); ``bias_cm``: its calibration's error (the same everywhere in its view); ``sigma_cm``: the noise of
    one detection; ``ramp_cm``: how far in from its view's edge its covariance starts to grow.
    """

    edge_id: str
    view: tuple[float, float, float, float]
    clock_offset_s: float = 0.0
    phase_s: float = 0.0
    bias_cm: tuple[float, float] = (0.0, 0.0)
    sigma_cm: float = 0.15
    ramp_cm: float = 12.0
    latency_s: float = 0.008

    def margin_cm(self, xy: tuple[float, float]) -> float:
        x0, y0, x1, y1 = self.view
        return min(xy[0] - x0, x1 - xy[0], xy[1] - y0, y1 - xy[1]) - MARKER_RADIUS_CM


def line(start: tuple[float, float], velocity_cm_s: tuple[float, float]) -> Path2D:
    return lambda t: (start[0] + velocity_cm_s[0] * t, start[1] + velocity_cm_s[1] * t)


def circle(centre: tuple[float, float], radius_cm: float, speed_cm_s: float, phase: float = 0.0) -> Path2D:
    w = speed_cm_s / radius_cm
    return lambda t: (centre[0] + radius_cm * math.cos(phase + w * t), centre[1] + radius_cm * math.sin(phase + w * t))


@dataclass
class Recording:
    """Each board's detections, and each message's true arrival time at the fuser (true clock)."""

    fps: float
    paths: dict[str, Path2D]
    boards: list[Board]
    frames: dict[str, list[Detections]] = field(default_factory=dict)
    arrivals: dict[tuple[str, int], float] = field(default_factory=dict)

    def truth(self, rover_id: str, t_s: float) -> tuple[float, float]:
        return self.paths[rover_id](t_s)

    def in_arrival_order(self) -> Iterator[tuple[float, Detections]]:
        every = [(self.arrivals[(d.edge_id, d.seq)], d) for frames in self.frames.values() for d in frames]
        yield from sorted(every, key=lambda item: item[0])


def record(
    boards: list[Board],
    paths: dict[str, Path2D],
    seconds: float,
    fps: float = 30.0,
    seed: int = 0,
) -> Recording:
    """Every board's detections of ``paths`` over ``seconds``."""
    rng = np.random.default_rng(seed)
    rec = Recording(fps, paths, boards)
    for board in boards:
        out = []
        for k in range(int(seconds * fps)):
            t_true = k / fps + board.phase_s
            if t_true < 0:
                continue
            rovers = []
            for rover_id, path in paths.items():
                xy = path(t_true)
                margin = board.margin_cm(xy)
                if margin <= 0:
                    continue
                scale = 1.0 if margin >= board.ramp_cm else board.ramp_cm / margin
                sigma = board.sigma_cm * scale
                noise = rng.normal(0.0, board.sigma_cm, 2)  # the noise itself does not grow: the trust does
                shown = (xy[0] + board.bias_cm[0] + noise[0], xy[1] + board.bias_cm[1] + noise[1])
                var = sigma * sigma + 0.05**2  # the calibration's own error, as the board's model states it
                rovers.append(Detection(rover_id, shown, (var, 0.0, var), None, 0.95, (640.0, 360.0)))
            t_board = t_true + board.clock_offset_s
            view = ((board.view[0], board.view[1]), (board.view[2], board.view[1]), (board.view[2], board.view[3]))
            d = Detections(
                board.edge_id, len(out), k, t_board, t_board + board.latency_s - 0.001, 1.0, view, tuple(rovers)
            )
            out.append(d)
            rec.arrivals[(board.edge_id, d.seq)] = t_true + board.latency_s
        rec.frames[board.edge_id] = out
    return rec
