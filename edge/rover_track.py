"""What the pipeline keeps about one rover between frames, and a measurement that passed its checks."""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from edge.filtering import ConstantVelocityFilter, HeadingFilter
from edge.tracker_config import RoverConfig
from edge.trackers.base import Measurement
from edge.two_tone import TwoToneHeading

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Observation:
    """A measurement that passed the pipeline's checks, with its covariance on the plane (cm^2)."""

    measurement: Measurement
    r_cm2: FloatArray


@dataclass
class RoverTrack:
    """The pipeline's mutable state for one rover."""

    config: RoverConfig
    index: int
    filter: ConstantVelocityFilter | None = None
    misses: int = 0
    level: float = 0.0
    areas: deque[float] = field(default_factory=lambda: deque(maxlen=31))
    box: tuple[int, int, int, int] | None = None
    uv: tuple[float, float] | None = None
    theta_rad: float | None = None
    heading: HeadingFilter = field(default_factory=HeadingFilter)  # a one-colour marker's heading through time
    two_tone: TwoToneHeading = field(default_factory=TwoToneHeading)  # a two-tone marker's heading through time
    seen: tuple[float, float, float] | None = None  # where (cm) and when (s, the stream's time) it was last measured
    offset_cm: tuple[float, float] = (0.0, 0.0)  # the centre correction last applied (edge.centre_offsets)

    @property
    def lost(self) -> bool:
        return self.filter is None

    @property
    def learned(self) -> bool:
        """Enough whole-marker areas seen to know this rover's own marker area."""
        return len(self.areas) >= 10

    def expected_area(self, nominal_cm2: float) -> float:
        """The marker area to expect: the median of this rover's recent areas once learned, within half to twice
        the nominal one."""
        if self.learned:
            learned = float(statistics.median(self.areas))  # 31 floats: plain Python is quicker
            return min(max(learned, 0.5 * nominal_cm2), 2.0 * nominal_cm2)
        return nominal_cm2

    def area_band(self, expected_cm2: float, min_fraction: float, max_fraction: float) -> tuple[float, float]:
        """The accepted blob area, as a share of the learned one: ``min_fraction``..``max_fraction``, widened to
        three robust standard deviations of this rover's own recent areas (a compressed stream's far-side areas
        scatter by 10 %; a marker a leg hides loses far more); the scatter widens the lower end to 0.75 at most,
        ``min_fraction`` below that lowers it further."""
        spread = 1.4826 * float(statistics.median(abs(a - expected_cm2) for a in self.areas)) / expected_cm2
        low = min(min_fraction, max(1.0 - 3.0 * spread, 0.75))
        return low, max(max_fraction, 1.0 + 3.0 * spread)

    def within_reach(self, xy_cm: tuple[float, float], t_s: float, max_speed_cm_s: float, slack_cm: float) -> bool:
        """Could the rover be at ``xy_cm`` at ``t_s``, driving at most ``max_speed_cm_s`` since it was last seen
        (``slack_cm`` more)? Always, before it has been seen at all."""
        if self.seen is None:
            return True
        x, y, t = self.seen
        return math.hypot(xy_cm[0] - x, xy_cm[1] - y) <= max_speed_cm_s * max(0.0, t_s - t) + slack_cm
