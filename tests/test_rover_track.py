"""A rover's learned marker area: the band a whole marker's blob must fall in, and when its area stays level."""

from __future__ import annotations

import pytest

from edge.rover_track import STEADY_FRAMES, STEADY_SLOPE, STEADY_STEP, RoverTrack, steady_areas
from edge.tracker_config import RoverConfig

LEVEL = [0.85, 0.84, 0.86, 0.83, 0.85, 0.84, 0.86, 0.85]  # a whole marker's area settled lower, 1 % scatter


@pytest.mark.parametrize(
    ("ratios", "level"),
    [
        (LEVEL, True),
        ([1.0, 0.98, 0.96, 0.94, 0.92, 0.90, 0.88, 0.86], False),  # hidden 2 % more of the marker each frame
        ([0.77, 0.79, 0.80, 0.81, 0.83, 0.84, 0.86, 0.87], False),  # coming out from behind a leg
        ([1.0, 1.0, 1.0, 0.99, 1.01, 1.0, 1.0, 0.86], False),  # hidden at once
        (LEVEL[:2], False),  # too few frames to tell
    ],
)
def test_areas_are_level_when_they_neither_keep_falling_or_rising_nor_step(ratios: list[float], level: bool) -> None:
    assert steady_areas(ratios, STEADY_SLOPE, STEADY_STEP) is level


def _track(areas: list[float]) -> RoverTrack:
    track = RoverTrack(RoverConfig(id="red", color_bgr=(40, 40, 200)), 0)
    track.areas.extend(areas)
    return track


def test_the_band_is_widened_by_the_scatter_above_the_learned_area_which_the_band_does_not_cut() -> None:
    """Areas below the band are never learned, so the scatter below the median looks smaller than it is; the scatter
    above it shows the stream's own (here 4 %, where the absolute deviations' median is 3 %)."""
    areas = [1.0] * 15 + [1.04] * 10 + [0.97] * 6
    low, high = _track(areas).area_band(1.0, 0.9, 1.3)
    assert low == pytest.approx(1.0 - 3.0 * 1.4826 * 0.04) and high == 1.3
    steady_low, _ = _track(areas).area_band(1.0, 0.9, 1.3, scatters=5.0)
    assert steady_low == 0.75  # never below LOWEST_AREA_FRACTION
    assert _track([1.0] * 31).area_band(1.0, 0.9, 1.3, scatters=5.0) == (0.9, 1.3)  # no scatter: the band itself


def test_a_rovers_areas_are_level_only_over_consecutive_measured_frames() -> None:
    assert len(LEVEL) == STEADY_FRAMES
    track = _track([1.0] * 31)
    for frame, ratio in enumerate(LEVEL):
        track.measured(frame if frame < 3 else frame + 1, ratio)  # frame 3 was not measured
    assert not track.steady(STEADY_FRAMES, 1.0)
    start = STEADY_FRAMES + 1
    for frame, ratio in enumerate(LEVEL, start=start):
        track.measured(frame, 0.5)
        track.measured(frame, ratio)  # the last blob measured in a frame counts
    assert track.steady(start + STEADY_FRAMES - 1, 1.0)
