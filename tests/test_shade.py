"""The shaded part of a marker that its threshold cut away (``edge.shade``): the pixels of the marker's hue and
relative saturation at a fraction of its brightness, joined to its mask; not a grey or other-hued neighbour, not
what lies apart from it, not the rover's body beside it (more than the marker lacks), and nothing when the mask
already holds the marker's size."""

from __future__ import annotations

import numpy as np

from edge.shade import SHADE_FILL, shaded_part

H, W = 40, 60
TOP, BOTTOM, LEFT, RIGHT = 10, 26, 12, 44  # the marker: 16 x 32 px
MARKER_PX = float((BOTTOM - TOP) * (RIGHT - LEFT))


def _scene(shade: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Opponent chroma and luminance of a warm floor (low saturation, its own hue) with a red-like marker (chroma
    along c1, relative saturation 0.8), the pixels ``shade`` of it at half its brightness, its colour kept; and
    the marker's pixels."""
    c1 = np.full((H, W), 8.0, np.float32)
    c2 = np.full((H, W), 16.0, np.float32)
    lum = np.full((H, W), 100.0, np.float32)
    marker = np.zeros((H, W), bool)
    marker[TOP:BOTTOM, LEFT:RIGHT] = True
    c1[marker], c2[marker], lum[marker] = 120.0, 0.0, 150.0
    if shade is not None:
        part = marker & shade
        c1[part], lum[part] = 60.0, 75.0
    return c1, c2, lum, marker


def _corner() -> np.ndarray:
    """A triangle at the marker's top left corner, 8 px along each side (a window bar's shadow across it)."""
    rows, cols = np.mgrid[0:H, 0:W]
    return (rows - TOP) + (cols - LEFT) < 8


def test_the_shaded_corner_the_threshold_cut_is_found_whole() -> None:
    corner = _corner()
    c1, c2, lum, marker = _scene(corner)
    mask = marker & ~corner  # the threshold at the sunlit level: the corner below it
    candidates = np.ones((H, W), bool)  # a warm floor in the marker's hue class, as wood is for red
    part = shaded_part(c1, c2, lum, candidates, mask, MARKER_PX)
    assert part is not None
    assert np.array_equal(part, marker & corner)


def test_nothing_is_taken_when_the_mask_holds_the_marker_s_size() -> None:
    corner = _corner()
    c1, c2, lum, marker = _scene(corner)
    mask = marker & ~corner
    assert shaded_part(c1, c2, lum, np.ones((H, W), bool), mask, 0.9 * float(np.count_nonzero(mask))) is None


def test_grey_other_hued_and_apart_pixels_are_not_the_marker_s_shade() -> None:
    corner = _corner()
    c1, c2, lum, marker = _scene(corner)
    mask = marker & ~corner
    grey = marker & corner & (np.arange(W)[None, :] < LEFT + 2)
    c1[grey], c2[grey] = 0.0, 0.0  # a grey object's pixels: no chroma
    other = marker & corner & (np.arange(W)[None, :] >= LEFT + 4)
    c1[other], c2[other] = 0.0, 60.0  # another hue at the marker's saturation
    apart = np.zeros((H, W), bool)
    apart[32:36, 2:8] = True  # the marker's colour in the shade, not joined to it
    c1[apart], c2[apart], lum[apart] = 60.0, 0.0, 75.0
    part = shaded_part(c1, c2, lum, np.ones((H, W), bool), mask, MARKER_PX)
    assert part is not None
    assert not (part & (grey | other | apart)).any()
    assert np.array_equal(part, marker & corner & ~grey & ~other)


def test_the_body_s_side_with_the_marker_s_chroma_spread_onto_it_is_not_a_shade() -> None:
    """A coarse stream spreads the marker's chroma onto the dark side of its body below it: its hue at a fraction of
    its brightness, over the whole side, far more than the few pixels the threshold left off the marker's edge."""
    c1, c2, lum, marker = _scene()
    mask = marker.copy()
    mask[BOTTOM - 1, :] = False  # the marker's last row, mixed with the body, under the threshold
    side = np.zeros((H, W), bool)
    side[BOTTOM : BOTTOM + 12, LEFT:RIGHT] = True
    c1[side], lum[side] = 40.0, 50.0
    c1[BOTTOM - 1, LEFT:RIGHT], lum[BOTTOM - 1, LEFT:RIGHT] = 70.0, 90.0
    held = float(np.count_nonzero(mask))
    assert held + 12 * (RIGHT - LEFT) > SHADE_FILL * MARKER_PX
    assert shaded_part(c1, c2, lum, np.ones((H, W), bool), mask, MARKER_PX) is None
