"""Trackers: the paper's three ways to measure a rover in its window, chosen by name.

``centroid`` (eq. 3-4), ``particles`` (Tables II-III, eq. 6-10) and ``meanshift`` (eq. 11-20) all implement
:class:`edge.trackers.base.WindowTracker`.
"""

from __future__ import annotations

from edge.trackers.base import Measurement, PlaneMapping, RoverModel, Window, WindowTracker
from edge.trackers.centroid import CentroidTracker
from edge.trackers.meanshift import MeanShiftTracker
from edge.trackers.particles import ParticleTracker

METHODS = ("centroid", "particles", "meanshift")
DEFAULT_METHOD = "particles"


def make_tracker(name: str) -> WindowTracker:
    """The window tracker called ``name`` (one of :data:`METHODS`) with its default settings."""
    if name == "centroid":
        return CentroidTracker()
    if name == "particles":
        return ParticleTracker()
    if name == "meanshift":
        return MeanShiftTracker()
    raise ValueError(f"unknown tracking method {name!r}; choose one of {', '.join(METHODS)}")


__all__ = [
    "DEFAULT_METHOD",
    "METHODS",
    "CentroidTracker",
    "MeanShiftTracker",
    "Measurement",
    "ParticleTracker",
    "PlaneMapping",
    "RoverModel",
    "Window",
    "WindowTracker",
    "make_tracker",
]
