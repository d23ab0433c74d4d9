"""The acquisition pass: which blobs of a lost rover's hue are tried first."""

from __future__ import annotations

import numpy as np

from edge.acquisition import CANDIDATES_PER_ROVER, candidates, low_resolution_view
from edge.segmentation import ColorModel

RED = (55, 85, 167)  # as the family's cross clip with seed 7777 rendered its red marker
GREEN = (88, 119, 86)


def _floor_with_a_cast(cast: tuple[int, int, int]) -> np.ndarray:
    """A 640 x 360 grey floor, with eight 40 x 40 px patches tinted a sixth of the way toward ``cast``."""
    image = np.full((360, 640, 3), 128, np.uint8)
    tint = np.rint(128 + (np.array(cast, np.float64) - 128) / 6).astype(np.uint8)
    for k in range(8):
        x, y = 20 + 75 * k, 40 + 30 * (k % 3)
        image[y : y + 40, x : x + 40] = tint
    return image


def test_the_marker_is_tried_before_larger_patches_with_a_weak_cast_of_its_hue() -> None:
    """Eight floor patches each larger than the marker, with a sixth of its chroma (a warm white balance and
    crosstalk give a grey floor such a cast): the marker, 12 x 8 px, is the first candidate. Ranked by area it was
    not among the six tried, and the rover stayed unfound."""
    colors = ColorModel.from_colors([RED, GREEN], 30.0, 0.1)
    image = _floor_with_a_cast(RED)
    image[300:308, 500:512] = RED
    view = low_resolution_view(image, 4, colors, None)
    assert np.count_nonzero(view.classes == 0) > 8 * 90  # the patches are of the marker's hue class, at 1/4 scale
    places = candidates(view, 0, colors)
    assert len(places) == CANDIDATES_PER_ROVER
    u, v = places[0]
    assert abs(u - 505.5) < 4.0 and abs(v - 303.5) < 4.0


def test_no_blob_of_the_hue_gives_no_candidate() -> None:
    colors = ColorModel.from_colors([RED, GREEN], 30.0, 0.1)
    view = low_resolution_view(np.full((120, 160, 3), 128, np.uint8), 4, colors, None)
    assert candidates(view, 0, colors) == []


def test_a_marker_touching_a_patch_with_a_weak_cast_of_its_hue_is_tried_where_the_marker_is() -> None:
    """The marker (12 x 8 px) lies against a 60 x 60 px floor patch with a sixth of its chroma: at a quarter of the
    resolution they make one blob, whose centroid is some 20 px from the marker. The candidate is placed on the
    blob's strong part, the marker, so the window measured there holds it."""
    colors = ColorModel.from_colors([RED, GREEN], 30.0, 0.1)
    image = np.full((360, 640, 3), 128, np.uint8)
    image[100:160, 300:360] = np.rint(128 + (np.array(RED, np.float64) - 128) / 6).astype(np.uint8)
    image[152:160, 360:372] = RED  # touching the patch's lower right corner
    view = low_resolution_view(image, 4, colors, None)
    labels = view.classes == 0
    assert np.count_nonzero(labels) > 200  # the patch is of the marker's hue class
    places = candidates(view, 0, colors)
    assert len(places) == 1  # one blob: the patch and the marker together
    u, v = places[0]
    assert abs(u - 365.5) < 4.0 and abs(v - 155.5) < 4.0


def test_a_marker_on_a_floor_of_its_own_hue_class_is_tried_where_the_marker_is() -> None:
    """A warm wooden floor: every pixel of the frame in the red marker's hue class, in planks at 0.35-0.55 of its
    chroma. Floor and marker are one blob; half the marker's peak took in the stronger planks, and the candidate,
    their centre with the marker's, lay far from the marker (the family's crowd clip with seed 4321 on wood: the
    orange marker was never tried). Halfway from the floor's level (the frame's median) to the peak, only the
    marker is left."""
    colors = ColorModel.from_colors([RED, GREEN], 30.0, 0.1)
    image = np.empty((360, 640, 3), np.uint8)
    for k in range(16):  # planks 40 px wide
        share = (0.35, 0.45, 0.55, 0.45)[k % 4]
        image[:, 40 * k : 40 * k + 40] = np.rint(128 + (np.array(RED, np.float64) - 128) * share).astype(np.uint8)
    image[300:308, 500:512] = RED
    view = low_resolution_view(image, 4, colors, None)
    assert np.count_nonzero(view.classes == 0) == view.classes.size  # the whole floor is of the marker's class
    u, v = candidates(view, 0, colors)[0]
    assert abs(u - 505.5) < 4.0 and abs(v - 303.5) < 4.0
