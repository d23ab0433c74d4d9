"""Centroid approach (paper section V.A, eq. 3-4): the centre of energy of the rover's binary plane.

Every pixel of the rover's colour that survives thresholding, erosion and hole filling in the search window
counts, with no choice among particles: simple and fast, but a speck of the same hue in the window pulls the
estimate (Table V: 'affected' by noise, spikes detected, filtration needed; the filter rejects the spikes).
Positions are the sub-pixel, perspective-correct area centroid with grey-level edge weights.
"""

from __future__ import annotations

import time

from edge.segmentation import dilate, erode, fill_holes
from edge.trackers.base import Measurement, RoverModel, StageClock, Window, measure_core, threshold_marker


class CentroidTracker:
    """Centre of energy (eq. 3-4) of all of the rover's pixels in the window, mapped to the plane."""

    name = "centroid"

    def __init__(self, threshold_fraction: float = 0.5, erosion_iterations: int = 1, ring_px: int = 2) -> None:
        self.threshold_fraction = threshold_fraction
        self.erosion_iterations = erosion_iterations
        self.ring_px = ring_px

    def reset(self, index: int) -> None:
        """Nothing to forget: every measurement starts from the window alone."""

    def measure(self, window: Window, rover: RoverModel, clock: StageClock) -> Measurement | None:
        found = threshold_marker(window, rover, self.threshold_fraction, clock)
        if found is None:
            return None
        candidates, mask = found
        t1 = time.perf_counter()
        # P.M.O.: erosion removes specks and leaves the marker's interior; the edge comes back as coverage weights.
        eroded = erode(mask, self.erosion_iterations)
        t2 = time.perf_counter()
        clock.add("erosion", t2 - t1)
        core = fill_holes(mask & dilate(eroded, self.erosion_iterations))  # A.M.O.
        clock.add("holes", time.perf_counter() - t2)
        if not core.any():
            return None
        return measure_core(window, rover, core, candidates, mask, self.ring_px, clock)  # eq. 3-4 on the plane
