"""Exact pixel coverage: the simulator's sub-pixel geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.sim.raster import coverage, polygon_area, polygon_centroid


@pytest.mark.parametrize(
    ("polygon", "expected"),
    [
        # a 2 x 2 px square centred on pixel (2, 2): one full pixel and eight partial ones
        ([[1.0, 1.0], [3.0, 1.0], [3.0, 3.0], [1.0, 3.0]], {(2, 2): 1.0, (1, 1): 0.25, (1, 2): 0.5, (2, 3): 0.5}),
        # pixel (1, 1) exactly: its square runs from 0.5 to 1.5
        ([[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]], {(1, 1): 1.0, (0, 0): 0.0, (1, 2): 0.0}),
        # a right triangle over pixel (1, 1): half of it
        ([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5]], {(1, 1): 0.5}),
        # a thin horizontal sliver a tenth of a pixel tall inside row 2
        ([[0.5, 2.2], [4.5, 2.2], [4.5, 2.3], [0.5, 2.3]], {(2, 1): 0.1, (2, 4): 0.1, (1, 1): 0.0, (3, 1): 0.0}),
    ],
)
def test_coverage_of_simple_shapes_is_their_area_in_each_pixel(polygon, expected):
    cov = coverage([np.array(polygon)], (0, 0), (6, 6))[0]
    for (row, col), value in expected.items():
        assert cov[row, col] == pytest.approx(value, abs=1e-12)


def test_winding_direction_does_not_matter():
    poly = np.array([[3.2, 1.7], [9.9, 2.4], [8.1, 7.3], [2.5, 6.6]])
    a = coverage([poly], (0, 0), (10, 12))[0]
    b = coverage([poly[::-1]], (0, 0), (10, 12))[0]
    np.testing.assert_allclose(a, b, atol=1e-12)


quads = st.lists(
    st.tuples(st.floats(2.0, 28.0), st.floats(2.0, 20.0)),
    min_size=3,
    max_size=8,
).map(lambda pts: np.array(pts))


def _convex(points: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise) of a few points, by angle around their mean."""
    c = points.mean(axis=0)
    order = np.argsort(np.arctan2(points[:, 1] - c[1], points[:, 0] - c[0]))
    return points[order]


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(quads)
def test_coverage_sums_to_the_polygon_area_and_stays_in_0_1(points):
    poly = _convex(points)
    area = abs(polygon_area(poly))
    cov = coverage([poly], (0, 0), (24, 32))[0]
    assert cov.min() >= 0.0
    assert cov.max() <= 1.0 + 1e-12
    assert cov.sum() == pytest.approx(area, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(quads, st.integers(0, 8), st.integers(0, 8))
def test_a_window_sees_exactly_its_part_of_the_full_coverage(points, dx, dy):
    poly = _convex(points)
    full = coverage([poly], (0, 0), (24, 32))[0]
    part = coverage([poly], (dx, dy), (10, 12))[0]
    np.testing.assert_allclose(part, full[dy : dy + 10, dx : dx + 12], atol=1e-12)


def test_coverage_weighted_centroid_matches_the_area_centroid_to_a_hundredth_of_a_pixel():
    # What a box-filtered pixel grid can do: the partial pixels' covered parts are not at their pixel centres,
    # which bounds the weighted centroid's error by a small fraction of a pixel even for tiny shapes.
    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(200):
        w, h, ang = rng.uniform(6, 40), rng.uniform(4, 30), rng.uniform(0, np.pi)
        base = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [0.7 * w / 2, h / 2], [-0.7 * w / 2, h / 2]])
        rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        poly = base @ rot.T + rng.uniform(30, 40, 2)
        cov = coverage([poly], (0, 0), (80, 80))[0]
        rows, cols = np.mgrid[0:80, 0:80]
        c = np.array([(cov * cols).sum(), (cov * rows).sum()]) / cov.sum()
        worst = max(worst, float(np.hypot(*(c - polygon_centroid(poly)))))
    assert worst < 0.02


def test_several_polygons_are_covered_independently():
    a = np.array([[1.0, 1.0], [4.0, 1.0], [4.0, 4.0], [1.0, 4.0]])
    b = a + 2.0
    both = coverage([a, b], (0, 0), (8, 8))
    np.testing.assert_allclose(both[0], coverage([a], (0, 0), (8, 8))[0])
    np.testing.assert_allclose(both[1], coverage([b], (0, 0), (8, 8))[0])


def test_polygon_outside_the_window_covers_nothing():
    poly = np.array([[50.0, 50.0], [60.0, 50.0], [60.0, 60.0]])
    assert coverage([poly], (0, 0), (10, 10)).sum() == 0.0
