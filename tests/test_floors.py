"""A floor of a hue near a marker's: the threshold is taken from the surround's level in the marker's plane
(``edge.trackers.base.surrounded``; docs/benchmarks.md, "Floors of other materials")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.segmentation import ThresholdInterval, auto_threshold, threshold
from edge.tracker_config import TrackerConfig
from edge.trackers.base import STANDOUT, SURROUND_IGNORED, surrounded
from edge.trackers.factory import build_tracker


def _window_plane(floor: float, noise: float, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A window's plane: a floor at ``floor`` (+- ``noise``) with a 24 x 30 marker at 100 in it, and the marker."""
    rng = np.random.default_rng(seed)
    plane = (floor + noise * rng.standard_normal((60, 80))).astype(np.float32)
    marker = np.zeros((60, 80), bool)
    marker[18:42, 25:55] = True
    plane[marker] = 100.0
    return plane, marker


def test_the_threshold_lies_halfway_between_a_coloured_floor_and_the_marker():
    """A floor at 0.47 of the marker's level in its plane (a warm wooden floor under a red marker): at half the
    marker's level most of the floor passed; taken halfway from the floor's level (less a tenth of the marker's),
    only the marker does."""
    plane, marker = _window_plane(47.0, 4.0)
    candidates = np.ones_like(marker)
    plain = auto_threshold(plane, candidates, 0.5)
    assert float(np.mean(threshold(plane, plain)[~marker])) > 0.2  # the floor passed
    interval = surrounded(plain, plane, 0.5)
    level = float(np.median(plane)) - SURROUND_IGNORED * plain.k_max  # the floor's level, from every 4th row
    assert interval.k_min == pytest.approx(level + 0.5 * (plain.k_max - level), abs=0.5)
    assert interval.k_max == plain.k_max
    passed = threshold(plane, interval)
    assert passed[marker].all() and not passed[~marker].any()


@pytest.mark.parametrize("floor", [0.0, 3.0, 8.0])
def test_a_grey_floor_leaves_the_threshold_at_half_the_marker_s_level(floor):
    """A grey floor's plane is 0 give or take the light's tint and the noise: up to a tenth of the marker's level
    it counts as 0, and the interval is the plain one."""
    plane, _ = _window_plane(floor, 2.0)
    plain = ThresholdInterval(50.0, 100.0)
    assert surrounded(plain, plane, 0.5) == plain


def test_a_window_of_a_floor_of_the_marker_s_hue_alone_holds_no_marker():
    """A window of wood alone, no marker in it: planks at 40, 47 and 56 in the red marker's plane (the simulator's
    wood: its brightest planks about 1.4 times its median). The interval's top is then the brightest planks', and
    halfway to it from the floor they passed, plank-sized, as a marker; nothing stands out from the floor, so there
    is no marker."""
    rng = np.random.default_rng(3)
    plane = np.repeat(np.array([40.0, 47.0, 56.0, 47.0] * 20, np.float32)[None, :], 60, axis=0)
    plane += rng.normal(0.0, 2.0, plane.shape).astype(np.float32)
    plain = auto_threshold(plane, np.ones(plane.shape, bool), 0.5)
    assert plain.k_max < STANDOUT * float(np.median(plane))
    assert surrounded(plain, plane, 0.5) is None


@pytest.mark.parametrize(("marker", "stands_out"), [(100.0, True), (1.6 * 47.0, True), (1.4 * 47.0, False)])
def test_a_marker_stands_out_from_a_floor_of_its_hue_class_by_its_level(marker, stands_out):
    """The marker's level against the floor's, in its plane: 1.5 times or more, it is thresholded halfway from the
    floor's level; less, nothing is taken for it."""
    plane, where = _window_plane(47.0, 1.0)
    plane[where] = marker
    interval = surrounded(auto_threshold(plane, np.ones_like(where), 0.5), plane, 0.5)
    assert (interval is not None) == stands_out
    if interval is not None:
        passed = threshold(plane, interval)
        assert passed[where].all() and not passed[~where].any()


@pytest.mark.slow
def test_a_red_rover_on_a_wooden_floor_is_found_in_every_frame() -> None:
    """The family's lens clip with seed 4321 (4:2:0 q85) on the simulator's wooden floor: the wood's plane is about
    half the red marker's, so at half the marker's level the floor passed with it, the blob joined the floor and
    was refused from frame 195, and the rover was lost for most of the run. Now it is found in every frame to 240,
    within 1 cm."""
    from tests.conftest import benchmark_module

    runs = benchmark_module("tracking_runs")
    clip = runs.render_clip("lens", 4321, 240, camera="family", floor="wood")
    tracker = build_tracker(
        TrackerConfig(rovers=clip.rovers, method="particles", fps=clip.fps), runs.plane_mapping(clip, "camera"), None
    )
    errors = {}
    for i, image in enumerate(clip.frames):
        for e in tracker.process(runs.frame_of(image, i, clip.fps)).estimates:
            if e.rover_id == "red":
                x, y = clip.truth[i]["red"][:2]
                errors[i] = math.hypot(e.x_cm - x, e.y_cm - y)
    seen = [i for i in range(len(clip.frames)) if clip.truth[i]["red"][5] >= 0.99]
    assert [i for i in seen if i not in errors] == []
    assert max(errors.values()) < 1.0, max(errors.values())
