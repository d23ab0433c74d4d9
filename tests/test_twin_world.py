"""The twin's world: bodies that cannot pass through each other, rovers picked up and put down elsewhere."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.errors import SimulationError
from edge.sim.contact import SolidWorld, push_apart_cm, separate
from edge.sim.metrics import box_corners_cm, min_body_gap_cm
from edge.sim.rover import BODY_LENGTH_CM, BODY_WIDTH_CM, MotorPhysics, drive_model, rover_config
from edge.sim.world import Pose, World

BODY = (BODY_LENGTH_CM, BODY_WIDTH_CM)
DRIVE = drive_model(rover_config("red"), MotorPhysics(gain_sigma=0.0, noise_sigma=0.0, delay_s=0.03))


def _poses(world: SolidWorld) -> np.ndarray:
    return np.array([(r.x_cm, r.y_cm, r.theta_rad) for r in world.state().rovers])


@pytest.mark.parametrize(
    ("b", "push"),
    [
        ((20.0, 0.0, 0.0), (2.0, 0.0)),  # end to end, 2 cm deep: out along x
        ((0.0, 15.0, 0.0), (0.0, 2.2)),  # side by side, 2.2 cm deep: out along y
        ((-21.0, 0.0, math.pi), (-1.0, 0.0)),  # facing each other, overlapping 1 cm: b goes back
    ],
)
def test_an_overlap_is_undone_by_the_shortest_push(b: tuple[float, float, float], push: tuple[float, float]) -> None:
    a_box = box_corners_cm(0.0, 0.0, 0.0, *BODY)
    b_box = box_corners_cm(*b, *BODY)
    got = push_apart_cm(a_box, b_box)
    assert got is not None
    assert got == pytest.approx(push, abs=1e-9)
    moved = box_corners_cm(b[0] + got[0], b[1] + got[1], b[2], *BODY)
    assert min_body_gap_cm(np.array([(0.0, 0.0, 0.0), (b[0] + got[0], b[1] + got[1], b[2])]), *BODY) == pytest.approx(
        0.0, abs=1e-9
    )
    assert moved.shape == (4, 2)


def test_boxes_apart_are_left_alone() -> None:
    assert push_apart_cm(box_corners_cm(0, 0, 0, *BODY), box_corners_cm(23, 0, 0, *BODY)) is None
    poses = np.array([(0.0, 0.0, 0.0), (100.0, 0.0, 1.0), (0.0, 100.0, 2.0)])
    assert np.all(separate(poses, *BODY) == 0.0)


def test_a_rover_squeezed_between_two_others_ends_clear_of_both() -> None:
    poses = np.array([(0.0, 0.0, 0.0), (18.0, 0.0, 0.0), (36.0, 0.0, 0.0)])
    moved = poses.copy()
    moved[:, :2] += separate(poses, *BODY)
    assert min_body_gap_cm(moved, *BODY) > -0.01  # a hundredth of a cm left, pushed out at the next sub-step


def test_two_rovers_driving_into_each_other_are_pressed_together_and_never_overlap() -> None:
    world = SolidWorld(
        {"red": Pose(100.0, 200.0, 0.0), "green": Pose(160.0, 205.0, math.pi)}, DRIVE, bodies_cm=BODY, seed=1
    )
    gaps = []
    for _ in range(300):  # 3 s of full speed head on
        world.step(0.01, {"red": (40.0, 0.0), "green": (40.0, 0.0)})
        gaps.append(min_body_gap_cm(_poses(world), *BODY))
    assert min(gaps) > -0.5  # at most a sub-step's travel between two pushes
    assert gaps[-1] < 0.5  # and they are touching: neither passed through


def test_the_same_rovers_in_the_world_of_the_closed_loop_pass_through_each_other() -> None:
    world = World({"red": Pose(100.0, 200.0, 0.0), "green": Pose(160.0, 205.0, math.pi)}, DRIVE, seed=1)
    for _ in range(300):
        world.step(0.01, {"red": (40.0, 0.0), "green": (40.0, 0.0)})
    s = world.state().by_id()
    assert s["red"].x_cm > s["green"].x_cm  # what SolidWorld is for


def test_a_placed_rover_is_where_it_was_put_with_its_wheels_stopped() -> None:
    world = SolidWorld({"red": Pose(100.0, 100.0, 0.0), "green": Pose(300.0, 300.0, 0.0)}, DRIVE, bodies_cm=BODY)
    for _ in range(50):
        world.step(0.01, {"red": (30.0, 0.0)})
    assert world.state().by_id()["red"].v_cm_s > 10.0
    world.place("red", Pose(50.0, 400.0, 4.0))
    red = world.state().by_id()["red"]
    assert (red.x_cm, red.y_cm, red.v_cm_s) == (50.0, 400.0, 0.0)
    assert red.theta_rad == pytest.approx(4.0 - 2 * math.pi)
    with pytest.raises(SimulationError, match="no rover 'blue'"):
        world.place("blue", Pose(0.0, 0.0, 0.0))
