"""Trackers: the paper's three ways to measure a rover in its window, chosen by name, and the parts they are built
with.

``centroid`` (eq. 3-4), ``particles`` (Tables II-III, eq. 6-10) and ``meanshift`` (eq. 11-20) all implement
:class:`edge.trackers.base.WindowTracker`. :func:`make_tracker` and :func:`make_filters` build them from the
configured settings; ``edge.trackers.factory.build_tracker`` builds a whole :class:`edge.tracking.Tracker`.
"""

from __future__ import annotations

from edge.filtering import ConstantVelocityFilterFactory, FilterFactory, FilterSettings
from edge.tracker_config import TrackerSettings
from edge.trackers.base import Measurement, PlaneMapping, RoverModel, Window, WindowTracker
from edge.trackers.centroid import CentroidTracker
from edge.trackers.meanshift import MeanShiftTracker
from edge.trackers.particles import ParticleTracker

METHODS = ("centroid", "particles", "meanshift")
DEFAULT_METHOD = "particles"


def make_tracker(name: str, settings: TrackerSettings | None = None) -> WindowTracker:
    """The window tracker called ``name`` (one of :data:`METHODS`) with the configured ``settings`` (defaults if
    None): the automatic threshold's ``threshold_fraction`` and the ``erosion_iterations`` of the binary trackers."""
    s = settings or TrackerSettings()
    if name == "centroid":
        return CentroidTracker(threshold_fraction=s.threshold_fraction, erosion_iterations=s.erosion_iterations)
    if name == "particles":
        return ParticleTracker(threshold_fraction=s.threshold_fraction, erosion_iterations=s.erosion_iterations)
    if name == "meanshift":
        return MeanShiftTracker()  # a histogram, not a threshold: neither setting applies
    raise ValueError(f"unknown tracking method {name!r}; choose one of {', '.join(METHODS)}")


def make_filters(settings: TrackerSettings | None = None) -> FilterFactory:
    """The per-rover filters with the configured process noise (``accel_sigma_cm_s2``)."""
    s = settings or TrackerSettings()
    return ConstantVelocityFilterFactory(FilterSettings(accel_sigma_cm_s2=s.accel_sigma_cm_s2))


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
    "make_filters",
    "make_tracker",
]
