"""Scenarios: each one builds for any seed, its rovers never touch, and it shows what its name promises."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.errors import SimulationError
from edge.sim.scenarios import SCENARIOS, build, get_scenario
from edge.sim.source import SimSource
from tests.support.sim import min_body_gap_cm

NAMES = ["lab", "drift", "sun", "cross", "occlusion", "lens", "crowd", "daylight"]


def test_the_issues_scenarios_are_all_there_with_one_line_of_help():
    assert list(SCENARIOS) == NAMES
    for s in SCENARIOS.values():
        assert s.summary and "\n" not in s.summary
    assert SCENARIOS["crowd"].default_rovers >= 12


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", [0, 7, 123])
def test_rovers_never_touch(name, seed):
    setup = build(name, seed=seed)
    assert min_body_gap_cm(setup) > 0.5


@pytest.mark.parametrize(
    ("name", "rovers"),
    [("lab", 8), ("crowd", 32), ("cross", 5), ("sun", 6), ("occlusion", 4), ("lens", 5), ("drift", 1)],
)
def test_other_fleet_sizes_build_and_never_touch(name, rovers):
    setup = build(name, seed=2, rovers=rovers, frames=90)
    assert len(setup.scene.rovers) == rovers
    assert len({look.rover_id for look in setup.scene.rovers}) == rovers
    assert min_body_gap_cm(setup) > 0.5


def test_default_fleet_is_red_green_blue():
    setup = build("lab")
    assert setup.rover_ids == ("red", "green", "blue")
    configs = setup.rover_configs()
    assert [c.id for c in configs] == ["red", "green", "blue"]
    assert configs[0].color_bgr[2] == max(configs[0].color_bgr)


@pytest.mark.parametrize("name", NAMES)
def test_seeds_vary_the_runs(name):
    a = build(name, seed=1).world().state_at(5.0)
    b = build(name, seed=2).world().state_at(5.0)
    assert a != b


@pytest.mark.parametrize("name", ["lab", "drift", "sun", "cross", "lens", "crowd", "daylight"])
def test_rovers_stay_on_the_floor_in_view(name):
    setup = build(name, seed=5)
    world = setup.world()
    for t in np.arange(0.0, setup.frames / setup.fps, 0.25):
        for r in world.state_at(float(t)).rovers:
            assert -45.0 < r.x_cm < AREA_WIDTH_CM + 45.0
            assert -5.0 < r.y_cm < AREA_LENGTH_CM + 25.0


def test_cross_passes_bodies_a_centimetre_apart_near_and_far():
    setup = build("cross", seed=0)
    world = setup.world()
    gaps = []
    for t in np.arange(0.0, setup.frames / setup.fps, 0.02):
        rovers = world.state_at(float(t)).by_id()
        gaps.append(
            (
                t,
                math.hypot(rovers["red"].x_cm - rovers["green"].x_cm, rovers["red"].y_cm - rovers["green"].y_cm),
                rovers["red"].y_cm,
            )
        )
    close = [(t, y) for t, d, y in gaps if d < 21.5]
    assert close, "red and green never pass each other"
    assert min(y for _, y in close) < 250.0  # a pass in the near half
    assert max(y for _, y in close) > 450.0  # and one at the far side
    assert min_body_gap_cm(setup, step_s=0.01) == pytest.approx(1.0, abs=0.15)


@pytest.mark.slow
def test_occlusion_hides_a_rover_behind_the_person_and_one_leaves_and_returns():
    source = SimSource("occlusion", seed=0, realtime=False, frames=450)
    source.open()
    seen: dict[str, list[float]] = {"red": [], "green": [], "blue": []}
    for i in range(0, 450, 5):
        source.render(i)
        for r in source.truth(i).rovers:
            seen[r.rover_id].append(r.visible)
    red, blue = np.array(seen["red"]), np.array(seen["blue"])
    assert red.max() > 0.99 and red.min() < 0.2  # hidden by the person for a while
    out = np.nonzero(blue == 0.0)[0]
    assert out.size > 0 and blue[0] > 0.99 and blue[-1] > 0.99 and blue[out[0] - 1] > 0  # left and came back


def test_lens_scenario_really_distorts():
    setup = build("lens")
    assert setup.camera.has_distortion
    corner = setup.camera.project(np.array([[0.0, 0.0, 13.0]]))[0]
    ideal = setup.camera.undistort_px(corner[None, :])[0]
    assert np.hypot(*(corner - ideal)) > 10.0
    assert setup.effects.compression is not None


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: get_scenario("moon"), "unknown scenario 'moon'; choose one of: lab, drift"),
        (lambda: build("lab", rovers=0), "--rovers must be at least 1"),
        (lambda: build("lab", frames=0), "--frames must be at least 1"),
        (lambda: build("crowd", rovers=400), "1 to 64"),
        (lambda: build("lab", floor="lava"), "--floor must be one of tiles, beige, wood, white, dark"),
    ],
)
def test_bad_scenario_requests_are_clear_errors(call, message):
    with pytest.raises(SimulationError, match=message):
        call()


def test_a_scenario_on_another_floor_shows_that_floor_and_keeps_all_else():
    """The floor's material is a choice of its own: the same seed on wood is the same run (world, camera, bodies),
    only the empty floor's colour changes: through the nominal camera warmer and darker than the default grey tiles,
    lighter on white. (A camera of the family with automatic white balance greys the wood, as a webcam's does.)"""
    tiles, wood = (build("lab", seed=3, frames=2, camera="family", floor=f) for f in ("tiles", "wood"))
    assert wood.camera_name == tiles.camera_name and wood.scene.rovers == tiles.scene.rovers
    assert tiles.scene.floor == build("lab", seed=3, frames=2, camera="family").scene.floor  # the default
    means = {}
    for name in ("tiles", "wood", "white"):
        image = build("lab", seed=3, frames=2, floor=name).renderer().background(0)
        h, w = image.shape[:2]
        b, g, r = image[h // 3 : 2 * h // 3, w // 3 : 2 * w // 3].reshape(-1, 3).mean(axis=0)  # the floor alone
        means[name] = (float(b), float(g), float(r))
    assert means["wood"][2] > means["wood"][0] + 30  # red well above blue: a warm floor
    assert abs(means["tiles"][2] - means["tiles"][0]) < 15  # the default is near grey
    assert sum(means["white"]) > sum(means["tiles"]) > sum(means["wood"])
