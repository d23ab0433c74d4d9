"""A blob's areas and shape held against the whole marker's: whether its areas over the last frames stay at one
level, and whether a blob below the area band is the whole marker worn down all round by the stream. Pure functions
over a rover's numbers (``edge.rover_track`` keeps them; docs/tracking.md, "Is it one whole marker?")."""

from __future__ import annotations

import statistics
from collections.abc import Sequence

from edge.blob_shape import eroded_elongation, point_asymmetry
from edge.trackers.base import Measurement

SYMMETRY_FLOOR = 0.8  # a blob below the area band but showing this share of the learned area may be whole ...
SYMMETRY_SKEW = 0.15  # ... when its point asymmetry (edge.blob_shape) is at most this
SYMMETRY_SHAPE = 0.05  # ... and its elongation within this share of a rectangle worn down all round to its area
SYMMETRY_STEP_CM = 0.75  # ... and its centre within this of where the rover's filter expects it
LEARN_SPAN = (0.8, 1.25)  # areas first learned: within this share of the nominal area (nominal_below, rover_track)


def symmetric_below(
    m: Measurement, ratio: float, aspect: float, innovation_cm: float | None, stretch: float = 1.0
) -> bool:
    """Is a blob showing ``ratio`` of the learned area, below the area band, the whole marker worn down all round by
    the stream (``edge.blob_shape``)? At least :data:`SYMMETRY_FLOOR` of the area, its point asymmetry at most
    :data:`SYMMETRY_SKEW`, its elongation (``aspect``: the marker's) within :data:`SYMMETRY_SHAPE` of a worn
    rectangle's (``stretch``: how much more floor its long sides lose than its ends, ``edge.blob_shape.wear_stretch``),
    and its centre within :data:`SYMMETRY_STEP_CM` of where the rover is expected (``innovation_cm``:
    :meth:`edge.rover_track.RoverTrack.step_cm`; None: nowhere known, not taken).

    A part hidden by a leg or a box makes the blob lopsided or, cut straight across, of the wrong elongation; of the
    hidden parts that pass both, one box's moves the centre 0.45 cm at most (tests/test_blob_shape.py). Strips
    hidden along an end and a side at once leave a smaller rectangle, symmetric and of a worn marker's shape,
    whose centre is off by the strips' width (1.1 cm at 0.85 of the area): the shape cannot tell, the filter's
    prediction can (docs/tracking.md, "Is it one whole marker?")."""
    if ratio < SYMMETRY_FLOOR or m.weights is None or innovation_cm is None:
        return False
    if not innovation_cm <= SYMMETRY_STEP_CM:
        return False
    if not abs(m.elongation / aspect / eroded_elongation(ratio, aspect, stretch) - 1.0) <= SYMMETRY_SHAPE:  # NaN: no
        return False
    return point_asymmetry(m.weights) <= SYMMETRY_SKEW


def nominal_below(m: Measurement, nominal_ratio: float, learned_ratio: float, innovation_cm: float | None) -> bool:
    """Is a blob below the area band the whole marker, the learned area having grown beyond the nominal one? Its
    area within :data:`LEARN_SPAN` of the nominal area (``nominal_ratio``) while the learned area is above that span
    (``learned_ratio``, also of the nominal), its point asymmetry at most :data:`SYMMETRY_SKEW` and its centre within
    :data:`SYMMETRY_STEP_CM` of where the rover is expected.

    In a window's daylight a white body's top takes the sky's blue; beside a blue marker the coverage counts it, the
    blob grows symmetric all round to 1.3-1.5 of the nominal area and the learned area follows it. Back under the
    lamps the whole marker shows 0.7-0.75 of that, below the band, and was refused in every frame (the daylight clip,
    seed 14641 on wood). A part hidden makes a blob lopsided; one cut straight across keeps it symmetric but moves its
    centre by half the cut, which the step bounds as it does for :func:`symmetric_below`. The shape is not asked: the
    body's top shows a margin of its own on each side (0.2-2.5 cm), so the grown blob's elongation is not the
    marker's."""
    if not back_to_nominal(nominal_ratio, learned_ratio) or m.weights is None or innovation_cm is None:
        return False
    return innovation_cm <= SYMMETRY_STEP_CM and point_asymmetry(m.weights) <= SYMMETRY_SKEW


def back_to_nominal(nominal_ratio: float, learned_ratio: float) -> bool:
    """Is a blob's area within :data:`LEARN_SPAN` of the nominal area (``nominal_ratio``) while the learned area has
    grown above that span (``learned_ratio``, also of the nominal)? Then :func:`nominal_below` may take it and the
    rover learns its area (``RoverTrack.learn``)."""
    low, high = LEARN_SPAN
    return low <= nominal_ratio <= high < learned_ratio


def steady_areas(ratios: Sequence[float], max_slope: float, max_step: float) -> bool:
    """Do consecutive frames' blob areas (``ratios``: shares of the learned area, oldest first) stay at one level?

    A marker a leg or a person hides shows less of its area from frame to frame (the visible share falls or, as it
    comes out, rises, by a few percent a frame), or at once; a whole marker's area in a compressed stream moves
    with the stream's chroma at its boundary: it may settle below its learned area for a while (the marker turns,
    its surround changes), scattered by a few percent a frame, but does not keep falling. Level: the least-squares
    slope over the frames is within ``max_slope`` per frame and the last ratio within ``max_step`` of the median of
    the ones before it."""
    n = len(ratios)
    if n < 3:
        return False
    mean_t = 0.5 * (n - 1)
    mean_r = sum(ratios) / n
    slope = sum((t - mean_t) * (r - mean_r) for t, r in enumerate(ratios)) / sum((t - mean_t) ** 2 for t in range(n))
    return abs(slope) <= max_slope and abs(ratios[-1] - statistics.median(ratios[:-1])) <= max_step
