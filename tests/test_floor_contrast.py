"""How far each marker stands out from the floor in its colour plane, as enrolment reports it
(``edge.floor_contrast``; the tracker's rule: ``edge.trackers.base.surrounded``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.enroll import enroll
from edge.floor_contrast import MARGINAL, contrast_warnings, floor_contrast
from edge.trackers.base import STANDOUT
from tests.support.lab import Lab, eight_hues, spread_out

RED = (40, 50, 200)


def _floor(share: float, size: tuple[int, int] = (120, 160)) -> np.ndarray:
    """An empty floor of grey 110 tinted ``share`` of the way toward RED's chroma (its level in red's plane is
    ``share`` times the marker's)."""
    grey = np.full((*size, 3), 110.0)
    tint = grey + share * (np.array(RED, np.float64) - np.mean(RED))
    return np.clip(np.rint(tint), 0, 255).astype(np.uint8)


@pytest.mark.parametrize(("share", "verdict"), [(0.0, None), (0.4, None), (0.6, "found only while"), (0.8, "will not")])
def test_a_marker_s_level_over_the_floor_s_is_measured_and_judged(share: float, verdict: str | None) -> None:
    """A floor at 0.4 of the red marker's level stands 2.5 times under it: nothing to say; at 0.6 (1.7 times) the
    tracker finds it only with little to spare; at 0.8 (1.25 times) not at all; a grey floor is not of its hue."""
    c = floor_contrast(_floor(share), "red", RED, (80.0, 60.0), 12.0)
    if share == 0.0:
        assert c.here == math.inf and c.worst == math.inf
    else:
        assert c.here == pytest.approx(1.0 / share, rel=0.03) and c.worst == pytest.approx(c.here, rel=0.01)
    lines = contrast_warnings([c], [(100.0, 200.0)])
    if verdict is None:
        assert lines == [] and c.here >= MARGINAL
    else:
        assert len(lines) == 1 and lines[0].startswith("red stands out only") and verdict in lines[0]
        assert (c.here < STANDOUT) == (verdict == "will not")


def test_the_floor_s_most_marker_like_place_is_named() -> None:
    """A grey floor with one warm patch (0.7 of the marker's level) away from the marker: fine where the marker
    stands, not on the patch, which is named."""
    floor = _floor(0.0)
    floor[10:50, 100:150] = _floor(0.7, (40, 50))
    c = floor_contrast(floor, "red", RED, (30.0, 90.0), 12.0)
    assert c.here == math.inf and c.worst < STANDOUT
    assert 100 <= c.worst_uv_px[0] < 150 and 10 <= c.worst_uv_px[1] < 50
    (line,) = contrast_warnings([c], [(312.0, 40.0)])
    assert "at (312, 40) cm on the floor" in line and "will not find it there" in line


@pytest.mark.slow
def test_enrolment_on_a_warm_wooden_floor_names_the_marker_it_nearly_defeats() -> None:
    """The eight-hue palette on the simulator's parquet under the paper's camera: the orange marker stands out
    from the wood 1.9 times in its plane at the wood's warmest, under the 2 that leave room for the light; red and
    yellow 2.4-2.6; the cool hues not at all (the wood is not of their hue). Only orange is named."""
    lab = Lab(eight_hues(), floor="wood")
    result = enroll(lab.frame(spread_out(8)), lab.background(), lab.calibration)
    floor_lines = [w for w in result.warnings if "from the floor" in w]
    assert len(floor_lines) == 1 and floor_lines[0].startswith("orange stands out only")
