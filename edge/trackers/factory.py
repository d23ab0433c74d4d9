"""``build_tracker``: the :class:`edge.tracking.Tracker` a configuration names, with every setting in place."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from edge.centre_offsets import Fits
from edge.pipeline import Pipeline
from edge.tracker_config import TrackerConfig
from edge.trackers.base import PlaneMapping
from edge.trackers.paper import PaperPipeline
from edge.tracking import Tracker


def build_tracker(
    config: TrackerConfig,
    calibration: PlaneMapping,
    background: NDArray[np.uint8] | None = None,
    *,
    fits: Fits | None = None,
) -> Tracker:
    """The tracker ``config.method`` names: the windowed :class:`edge.pipeline.Pipeline` (its window tracker, the
    acquisition's particle tracker and the filters built by ``edge.trackers.make_tracker``/``make_filters`` from
    ``config``), or the paper's full-frame baseline (``method="paper"``).

    ``calibration``: the pixel <-> plane mapping; ``background``: an empty-scene frame, or None to learn it;
    ``fits``: where the ``edge_offsets`` setting's edge fits run (``edge.centre_offsets``; default: a worker process).
    """
    if config.method == "paper":
        return PaperPipeline(config, calibration, background)
    return Pipeline(config, calibration, background, fits=fits)
