"""Particle measurements (paper section V.B, Tables II-III, eq. 6-10): the marker is one particle among several.

The binary marker mask is split into particles; each is measured (area, holes, convex hull, bounding rectangle,
centre of mass) and the one that is the marker is chosen by area and position, so clutter of the same hue and
speckle noise cannot pull the estimate (Table V: noise 'controllable', no spikes). Its position is then the
sub-pixel, perspective-correct area centroid of the chosen particle with grey-level edge weights.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numpy.typing import NDArray

from edge.blob_shape import marker_part
from edge.segmentation import (
    Particle,
    fill_holes,
    label_particles,
    open_by_reconstruction,
    outline_particle,
    single_outline,
)
from edge.trackers.base import Measurement, RoverModel, StageClock, Window, measure_core, threshold_marker
from edge.trackers.base import expected_px as marker_px

JOINED_AREA = 1.08  # a blob this much larger than the marker is looked at for a part joined to it (marker_part)


class ParticleTracker:
    """Choose the marker's particle by area (Table II) and nearness to the prediction; centre of mass in world."""

    name = "particles"

    def __init__(
        self,
        threshold_fraction: float = 0.5,
        erosion_iterations: int = 1,
        ring_px: int = 2,
        min_area_fraction: float = 0.2,
        max_area_fraction: float = 3.0,
    ) -> None:
        self.threshold_fraction = threshold_fraction
        self.erosion_iterations = erosion_iterations
        self.ring_px = ring_px
        self.min_area_fraction = min_area_fraction
        self.max_area_fraction = max_area_fraction

    def reset(self, index: int) -> None:
        """Nothing to forget: every measurement starts from the window alone."""

    def measure(self, window: Window, rover: RoverModel, clock: StageClock) -> Measurement | None:
        found = threshold_marker(window, rover, self.threshold_fraction, clock)
        if found is None:
            return None
        candidates, mask = found
        expected_px = marker_px(window, rover)
        min_area_px = max(2, int(self.min_area_fraction * expected_px))
        t1 = time.perf_counter()
        single = single_outline(mask, self.erosion_iterations)  # one particle (a tracked marker's, nearly always)
        if single is None:
            mask, holes = open_by_reconstruction(mask, self.erosion_iterations), True  # P.M.O.
        else:  # the opening keeps the one particle whole (the mask is its own opening); its outline gives Table II
            outline, holes, eroded = single
        t2 = time.perf_counter()
        clock.add("erosion", t2 - t1)
        filled = fill_holes(mask) if holes else mask  # A.M.O.
        t3 = time.perf_counter()
        clock.add("holes", t3 - t2)
        labels: NDArray[np.int32] | None = None
        if single is not None:
            particles = outline_particle(filled, outline, min_area_px)
        else:
            labels, particles = label_particles(filled, min_area_px=min_area_px, filled=True)
        chosen = self._choose(particles, labels, window, expected_px, clock)
        clock.add("measure", time.perf_counter() - t3)
        if not chosen:
            return None
        interior = None
        if labels is None:  # the one particle: its filled mask is the core
            core = filled
            # a mask without holes is its own core: its erosion by one is the core's interior
            interior = eroded if not holes and self.erosion_iterations == 1 else None
        else:
            core = np.isin(labels, [p.label for p in chosen]) if len(chosen) > 1 else labels == chosen[0].label
        parted = None
        if sum(p.total_px for p in chosen) > JOINED_AREA * expected_px:  # the marker joined to something of its hue?
            ox, oy = window.offset
            parted = marker_part(core, expected_px, (window.predicted_uv[0] - ox, window.predicted_uv[1] - oy))
            if parted is not None:
                core, interior = parted[0], None
        rest = None if parted is None else parted[1]
        return measure_core(window, rover, core, candidates, mask, self.ring_px, clock, interior, rest)  # eq. 9-10

    def _choose(
        self,
        particles: list[Particle],
        labels: NDArray[np.int32] | None,
        window: Window,
        expected_px: float,
        clock: StageClock,
    ) -> list[Particle]:
        """The marker's particle, plus any fragments of it (a marker split by a glare band stays whole).

        Particles are scored by area (Table II) and solidity, and by nearness to the prediction; when several
        qualify, background subtraction (eq. 2) adds what share of each differs from the empty scene; and a particle
        that is part of the empty scene (under a fifth of it differs: a sticker, a poster of the same hue) is never
        the rover while another one differs from it (over half), however near the prediction it lies.
        ``labels``: the label image of several particles (None with one).
        """
        if not particles:
            return []
        ox, oy = window.offset  # particles are measured in window pixels, the prediction is in image pixels
        pu, pv = window.predicted_uv[0] - ox, window.predicted_uv[1] - oy
        radius_px = math.sqrt(max(expected_px, 1.0) / math.pi)

        def score(p: Particle) -> float:
            ratio = p.total_px / expected_px if expected_px > 0 else 1.0
            if not self.min_area_fraction <= ratio <= self.max_area_fraction:
                return -math.inf
            dist = math.hypot(p.centre_px[0] - pu, p.centre_px[1] - pv) / radius_px
            return min(ratio, 1.0) * p.solidity - 0.25 * dist

        scores = {p.label: score(p) for p in particles}
        plausible = [p for p in particles if scores[p.label] > -math.inf]
        if len(plausible) > 1:
            assert labels is not None  # None only with one particle
            t0 = time.perf_counter()
            differs = {p.label: window.foreground_fraction(labels == p.label) for p in plausible}
            for p in plausible:
                scores[p.label] += 0.5 * differs[p.label]
            if max(differs.values()) > 0.5:  # part of the empty scene loses to what differs from it
                for p in plausible:
                    if differs[p.label] < 0.2:
                        scores[p.label] = -math.inf
            clock.add("subtraction", time.perf_counter() - t0)
        best = max(particles, key=lambda p: scores[p.label])
        if scores[best.label] == -math.inf:
            return []
        bx, by = best.centre_px
        parts = [best]
        for p in particles:
            if p is not best and math.hypot(p.centre_px[0] - bx, p.centre_px[1] - by) < 1.5 * radius_px:
                parts.append(p)
        total = sum(p.total_px for p in parts)
        if expected_px > 0 and total > self.max_area_fraction * expected_px:
            return [best]
        return parts
