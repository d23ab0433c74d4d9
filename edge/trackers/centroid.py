"""Centroid approach (paper section V.A, eq. 3-4): the centre of energy of the rover's binary plane.

Every pixel of the rover's colour that survives thresholding, erosion and hole filling in the search window
counts, with no choice among particles: simple and fast, but a speck of the same hue in the window pulls the
estimate (Table V: 'affected' by noise, spikes detected, filtration needed; the filter rejects the spikes).
Positions are the sub-pixel, perspective-correct area centroid with grey-level edge weights.
"""

from __future__ import annotations

import time

from edge.segmentation import (
    auto_threshold,
    coverage_weights,
    dilate,
    erode,
    fill_holes,
    marker_level,
    threshold,
)
from edge.trackers.base import (
    Measurement,
    RoverModel,
    StageClock,
    Window,
    area_quality,
    make_measurement,
    world_blob,
)


class CentroidTracker:
    """Centre of energy (eq. 3-4) of all of the rover's pixels in the window, mapped to the plane."""

    name = "centroid"

    def __init__(self, threshold_fraction: float = 0.5, erosion_iterations: int = 1, ring_px: int = 2) -> None:
        self.threshold_fraction = threshold_fraction
        self.erosion_iterations = erosion_iterations
        self.ring_px = ring_px

    def measure(self, window: Window, rover: RoverModel, clock: StageClock) -> Measurement | None:
        t0 = time.perf_counter()
        candidates = window.classes == rover.index
        if not candidates.any():
            clock.add("threshold", time.perf_counter() - t0)
            return None
        interval = auto_threshold(window.plane, candidates, self.threshold_fraction)
        mask = candidates & threshold(window.plane, interval)
        t1 = time.perf_counter()
        clock.add("threshold", t1 - t0)
        # P.M.O.: erosion removes specks and leaves the marker's interior; the edge comes back as coverage weights.
        eroded = erode(mask, self.erosion_iterations)
        t2 = time.perf_counter()
        clock.add("erosion", t2 - t1)
        core = fill_holes(mask & dilate(eroded, self.erosion_iterations))  # A.M.O.
        t3 = time.perf_counter()
        clock.add("holes", t3 - t2)
        if not core.any():
            return None
        level = marker_level(window.plane, core)
        others = (window.classes >= 0) & ~candidates
        weights = coverage_weights(window.bgr, window.lum, core, self.ring_px, exclude=others, pure=mask)
        t4 = time.perf_counter()
        clock.add("measure", t4 - t3)
        blob = world_blob(weights, window.offset, window.grid)  # eq. 3-4
        clock.add("calibration", time.perf_counter() - t4)
        if blob is None:
            return None
        quality = area_quality(blob.area_cm2, rover.marker_area_cm2)
        return make_measurement(blob, window, core, level, quality, weights)
