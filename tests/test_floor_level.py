"""The floor's own level under every pixel (``edge.trackers.base.above_floor``): a warm floor in two lights (the
edge of a sunlit patch beside a marker) has two levels in the marker's plane, and the window's median is the
shaded one's; the background model's reference knows both. It is used where the floor joined the marker
(``joined_to_floor``), at the pixels that show the empty scene. And what the reference showed while a rover was
unseen is not taken for the floor once it is found (``BackgroundModel.valid_since``, ``forget``)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from edge.background import BackgroundModel
from edge.camera import MARKER_HEIGHT_CM
from edge.segmentation import ColorModel
from edge.trackers.base import SURROUND_IGNORED, NullClock, PlaneGrid, RoverModel, above_floor, threshold_marker
from edge.trackers.window import Window, prepare_window
from tests.support.track import COLORS, SynthRover, _rect, shared_scene

WARM = (0.62, 0.8, 1.12)  # BGR factors that make the grey tiles a warm floor, about half a red marker in its plane
SUN = (1.2, 1.35, 1.45)  # the sunlit patch: brighter and warmer


def _window(
    image: np.ndarray, box: tuple[int, int, int, int], uv: tuple[float, float], empty: np.ndarray | None
) -> Window:
    """The red rover's window ``box`` of ``image`` (red, green and blue rovers), as the pipeline prepares it, with
    ``empty`` as the background reference (or none)."""
    window = prepare_window(
        image,
        box,
        rover_index=0,
        predicted_uv=uv,
        colors=ColorModel.from_colors([COLORS["red"], COLORS["green"], COLORS["blue"]], 30.0, 0.35),
        maps=PlaneGrid(shared_scene().mapping, (image.shape[1], image.shape[0])),
        background=BackgroundModel(image.shape[:2], 100, empty),
        background_threshold=0.2,
        clock=NullClock(),
    )
    assert window is not None
    return window


def _beside_the_sun(known: bool, sun_from_px: int = 18) -> tuple[Window, np.ndarray]:
    """A red marker on a warm floor, a sunlit patch starting ``sun_from_px`` right of its centre (it reaches 60 px
    up and down from it); the window around it prepared with the empty floor as the background reference
    (``known``) or with none. Also where the marker is (window pixels)."""
    scene = shared_scene()
    rover = SynthRover("red", 150.0, 200.0, 0.0, COLORS["red"])
    uv = scene.camera.project(np.array([[rover.x, rover.y, MARKER_HEIGHT_CM]]))[0]
    u, v = int(uv[0]), int(uv[1])
    grey = scene.floor
    try:
        scene.floor = np.clip(grey.astype(np.float32) * np.float32(WARM), 0, 255).astype(np.uint8)
        sun = ((u + sun_from_px, v - 60, u + 200, v + 60), SUN)
        empty, image = scene.render([], sun=sun), scene.render([rover], sun=sun)
    finally:
        scene.floor = grey
    box = (u - 40, v - 25, u + 40, v + 25)
    window = _window(image, box, (float(uv[0]), float(uv[1])), empty if known else None)
    corners = scene.camera.project(_rect(rover.x, rover.y, rover.theta, *rover.marker_cm, MARKER_HEIGHT_CM))
    marker = np.zeros(window.plane.shape, np.uint8)
    cv2.fillPoly(marker, [np.rint((corners - box[:2]) * 16).astype(np.int32)], 1, shift=4)
    return window, marker.astype(bool)


def test_a_marker_beside_a_sunlit_patch_of_a_warm_floor_is_thresholded_against_the_floor_under_each_pixel() -> None:
    """Without the reference the sunlit floor is above the bound halfway from the shaded floor (the window's
    median) to the marker, and joins the marker's blob (the family's sun clip with seed 16661 on wood: the red
    rover refused as 2-3 times its area); with it each pixel's bound starts from its own floor, and only the marker
    passes."""
    window, marker = _beside_the_sun(known=False)
    found = threshold_marker(window, RoverModel(0, 22.0 * 17.0, 0.0), 0.5, NullClock())
    assert found is not None
    assert np.count_nonzero(found[1] & ~marker) > 0.8 * np.count_nonzero(marker)  # the sunlit floor joined it

    window, marker = _beside_the_sun(known=True)
    found = threshold_marker(window, RoverModel(0, 22.0 * 17.0, 0.0), 0.5, NullClock())
    assert found is not None
    mask = found[1]
    ring = cv2.dilate(marker.view(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)  # its blurred edge
    assert not np.count_nonzero(mask & ~ring)
    assert np.count_nonzero(mask & marker) >= 0.9 * np.count_nonzero(marker)


def test_the_floor_under_the_rover_s_body_is_not_the_floor_round_its_marker() -> None:
    """A rover standing in the sunlit patch: round its marker the image shows its dark body, the reference the
    sunlit wood the body now hides. Held against that wood's level the marker's edge pixels on the body were cut
    off; they are not the empty scene (eq. 2), and the floor's level under them is not used. The sunlit wood round
    the body still is the floor."""
    window, marker = _beside_the_sun(known=True, sun_from_px=-60)
    k_max = float(np.percentile(window.plane[marker], 90))
    above = above_floor(window, k_max, 0.5)
    assert above is not None
    near = cv2.dilate(marker.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    floor = window.floor_plane
    assert floor is not None
    level = np.maximum(floor - SURROUND_IGNORED * k_max, 0.0)
    half = window.plane >= level + 0.5 * (k_max - level)
    # the edge's pixels, at least half marker, mixed with the dark body
    edge = near & (window.plane >= 0.5 * k_max) & (window.plane < 0.85 * k_max)
    assert np.count_nonzero(edge) >= 10
    assert np.count_nonzero(edge & ~half) > 0.5 * np.count_nonzero(edge)  # the wood's level would cut them
    assert above[edge].all()
    assert not above[:, -10:].any()  # the sunlit wood beside the body, at its own level


def _grey_window(known: bool) -> Window:
    scene = shared_scene()
    rover = SynthRover("red", 150.0, 200.0, 0.0, COLORS["red"])
    uv = scene.camera.project(np.array([[rover.x, rover.y, MARKER_HEIGHT_CM]]))[0]
    u, v = int(uv[0]), int(uv[1])
    box = (u - 40, v - 25, u + 40, v + 25)
    return _window(scene.render([rover]), box, (float(uv[0]), float(uv[1])), scene.render([]) if known else None)


def test_the_floor_s_own_level_changes_nothing_on_grey_tiles_and_says_nothing_where_the_floor_is_not_known() -> None:
    """On grey tiles the floor's level in the marker's plane is under a tenth of the marker's and counts as 0
    (``SURROUND_IGNORED``): the same mask with the floor known as without. Without a reference there is nothing
    to say."""
    window, _ = _beside_the_sun(known=False)
    assert above_floor(window, 100.0, 0.5) is None
    masks = []
    for known in (False, True):
        found = threshold_marker(_grey_window(known), RoverModel(0, 22.0 * 17.0, 0.0), 0.5, NullClock())
        assert found is not None
        masks.append(found[1])
    assert np.count_nonzero(masks[0]) > 300 and np.array_equal(masks[0], masks[1])


def test_the_reference_copied_while_a_rover_was_unseen_is_not_the_floor_once_it_is_found() -> None:
    """The model's first frame is copied whole; a rover not found in it is in the reference, marked valid. Found
    later, what was copied since it was unseen is not the floor under it (``valid_since``), and once found, those
    pixels are forgotten (``forget``) so the band's refresh, which then leaves its box alone, cannot make them valid
    again. Rows copied before it went unseen, and pixels away from it, keep their validity."""
    h, w = 40, 60
    floor = np.full((h, w, 3), 120, np.uint8)
    scene = floor.copy()
    scene[10:20, 10:20] = COLORS["red"]  # a rover no one has found yet
    model = BackgroundModel((h, w), period_frames=4)
    model.refresh(scene, exclude=[])
    assert model.valid.all()  # it is in the reference, and the reference is "the floor"
    box = (5, 5, 25, 25)
    assert not model.valid_since(box, 0).any()  # unseen since the start: nothing there is known
    assert model.valid_since(box, 1).all()  # a rover unseen only from the next refresh on
    for _ in range(3):
        model.refresh(scene, exclude=[])  # rows 0-9, 10-19, 20-29 again, in refreshes 1-3
    since = 2  # unseen since refresh 2: rows 10-19 (refresh 2) and 20-29 (refresh 3) may show it
    seen = model.valid_since(box, since)
    assert seen[:5].all() and not seen[5:].any()  # rows 5-9 (refresh 1) were copied before
    marker = np.zeros((20, 20), np.float32)
    marker[7:13, 7:13] = 1.0  # the marker's coverage in the box: FORGET_PX round it are forgotten too
    model.forget(box, since, marker)
    assert not model.valid[10:20, 10:20].any()
    assert model.valid[5:10, 5:25].all() and model.valid[20:25, 5:8].all()  # before `since`, or away from it
    assert model.valid[:, 30:].all()
    model.refresh(scene, exclude=[(8, 8, 22, 22)])  # tracked now: its box is left alone
    model.refresh(scene, exclude=[(8, 8, 22, 22)])
    assert not model.valid[10:20, 10:20].any()


@pytest.mark.parametrize("since", [0, 3])
def test_an_empty_scene_given_at_the_start_stays_the_floor_where_it_has_not_been_copied_over(since: int) -> None:
    """Given an empty scene, the rows no refresh has copied since still show it, whoever went unseen when."""
    h, w = 40, 60
    model = BackgroundModel((h, w), period_frames=4, empty_scene=np.full((h, w, 3), 120, np.uint8))
    for _ in range(since + 1):
        model.refresh(np.full((h, w, 3), 121, np.uint8), exclude=[])
    copied = math.ceil(h / 4) * (since + 1)
    seen = model.valid_since((0, 0, w, h), since)
    assert seen[copied:].all() and not seen[copied - 10 : copied].any()
