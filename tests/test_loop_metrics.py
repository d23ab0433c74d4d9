"""The closed loop's pure parts: formation metrics, body gaps, starting layouts, the rover described once."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.camera import AREA_LENGTH_CM, AREA_WIDTH_CM
from edge.errors import ConfigError
from edge.sim.loop import LoopConfig
from edge.sim.metrics import (
    Bar,
    box_corners_cm,
    box_gap_cm,
    converged_frame,
    enclosing_diameter_cm,
    formation_error,
    line_errors,
    min_body_gap_cm,
    min_centre_distance_cm,
    polygon_sides_cm,
)
from edge.sim.rover import (
    BODY_LENGTH_CM,
    BODY_WIDTH_CM,
    MotorPhysics,
    drive_model,
    fleet_drive_model,
    rover_config,
    rover_looks,
)
from edge.sim.starts import random_layout, trajectory_plans


def triangle(side: float, centre: tuple[float, float] = (100.0, 200.0), turn: float = 0.3) -> np.ndarray:
    r = side / math.sqrt(3.0)
    a = turn + np.arange(3) * 2 * math.pi / 3
    return np.column_stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a)])


@pytest.mark.parametrize(
    ("points", "diameter"),
    [
        ([[0, 0]], 0.0),
        ([[0, 0], [30, 40]], 50.0),
        ([[0, 0], [10, 0], [20, 0]], 20.0),  # collinear: the two ends
        (triangle(34.0).tolist(), 2 * 34.0 / math.sqrt(3.0)),  # equilateral: the circumcircle
        ([[0, 0], [40, 0], [20, 1]], 40.0),  # obtuse: the longest side
        ([[0, 0], [40, 0], [0, 40], [40, 40], [20, 20]], 40.0 * math.sqrt(2.0)),
    ],
)
def test_enclosing_diameter_is_the_smallest_circle(points: list[list[float]], diameter: float) -> None:
    assert enclosing_diameter_cm(np.asarray(points, dtype=float)) == pytest.approx(diameter, abs=1e-9)


@pytest.mark.parametrize(
    ("points", "displacement", "gaps"),
    [
        ([[100, 100], [100, 160], [100, 220]], 0.0, [60, 60]),
        ([[102, 220], [98, 100], [100, 160]], 2.0, [60, 60]),  # order by y, not by id
        ([[100, 100], [100, 155], [100, 220]], 0.0, [55, 65]),
    ],
)
def test_line_errors_measure_offsets_from_the_mean_x_and_gaps_along_y(
    points: list[list[float]], displacement: float, gaps: list[float]
) -> None:
    d, _, g = line_errors(np.asarray(points, dtype=float))
    assert d == pytest.approx(displacement)
    assert g.tolist() == pytest.approx(gaps)


@pytest.mark.parametrize(
    ("kind", "points", "holds"),
    [
        ("line", [[100, 100], [102.9, 160], [100, 220]], True),  # 1.93 cm off the mean x
        ("line", [[100, 100], [100, 163.5], [100, 220]], False),  # a gap 3.5 cm long
        ("line", [[95, 100], [100, 160], [105, 220]], False),  # 5 cm off the line
        ("rendezvous", triangle(34.0).tolist(), True),  # 39.3 cm across
        ("rendezvous", triangle(35.0).tolist(), False),  # 40.4 cm across
        ("triangle", triangle(100.0).tolist(), True),
        ("triangle", (triangle(100.0) * [1.0, 1.04]).tolist(), False),
    ],
)
def test_the_bar_holds_only_inside_its_tolerance(kind: str, points: list[list[float]], holds: bool) -> None:
    assert (formation_error(Bar(kind), np.asarray(points, dtype=float)) <= 0) is holds


def test_polygon_sides_follow_the_ring_not_the_ids() -> None:
    square = np.array([[0, 0], [50, 50], [50, 0], [0, 50]], dtype=float)
    assert polygon_sides_cm(square).tolist() == pytest.approx([50.0] * 4)


@pytest.mark.parametrize(
    ("errors", "frame"),
    [
        ([5, 3, -1, -1], 2),
        ([5, -1, 2, -1, -1], 3),  # out again: counts from the last time it held for good
        ([-1, -1], 0),
        ([5, -1, 1], None),  # not holding at the end
        ([], None),
    ],
)
def test_converged_frame_is_where_the_bar_holds_to_the_end(errors: list[float], frame: int | None) -> None:
    assert converged_frame(errors) == frame


@pytest.mark.parametrize(
    ("a", "b", "gap"),
    [
        ((0, 0, 0), (40, 0, 0), 40 - 22.0),  # end to end along x
        ((0, 0, 0), (0, 30, 0), 30 - 17.2),  # side by side
        ((0, 0, math.pi / 2), (0, 30, math.pi / 2), 30 - 22.0),
        ((0, 0, 0), (21, 0, 0), -1.0),  # overlapping by 1 cm
        ((0, 0, 0), (0, 0, 1.0), None),  # same place: overlapping
    ],
)
def test_box_gap_is_the_distance_between_bodies(a: tuple[float, ...], b: tuple[float, ...], gap: float | None) -> None:
    g = box_gap_cm(box_corners_cm(*a, 22.0, 17.2), box_corners_cm(*b, 22.0, 17.2))
    if gap is None:
        assert g < 0
    else:
        assert g == pytest.approx(gap, abs=1e-9)


def test_corner_to_corner_gap_is_euclidean() -> None:
    half_diagonal = 0.5 * math.hypot(22.0, 17.2)
    angle = math.atan2(17.2, 22.0)
    d = 2 * half_diagonal + 5.0
    a = (0.0, 0.0, -angle)  # its corner points along +x
    b = (d, 0.0, math.pi - angle)  # its corner points along -x
    assert box_gap_cm(box_corners_cm(*a, 22.0, 17.2), box_corners_cm(*b, 22.0, 17.2)) == pytest.approx(5.0, abs=1e-9)


def test_min_distances_over_a_fleet() -> None:
    poses = np.array([[0, 0, 0], [100, 0, 0], [0, 25, 0]], dtype=float)
    assert min_centre_distance_cm(poses[:, :2]) == pytest.approx(25.0)
    assert min_body_gap_cm(poses, 22.0, 17.2) == pytest.approx(25.0 - 17.2)
    assert math.isinf(min_body_gap_cm(poses[:1], 22.0, 17.2))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 4))
def test_random_layouts_are_apart_inside_the_area(seed: int, n: int) -> None:
    starts = random_layout(n, np.random.default_rng(seed), 150.0, 40.0)
    xy = np.array([[p.x_cm, p.y_cm] for p in starts])
    assert min_centre_distance_cm(xy) >= 150.0
    assert np.all((xy[:, 0] >= 40.0) & (xy[:, 0] <= AREA_WIDTH_CM - 40.0))
    assert np.all((xy[:, 1] >= 40.0) & (xy[:, 1] <= AREA_LENGTH_CM - 40.0))


def test_the_simulated_rover_is_the_rover_the_firmware_config_describes() -> None:
    cfg = rover_config("red")
    drive = drive_model(cfg, MotorPhysics())
    g, m = cfg["geometry"], cfg["motors"]
    assert drive.track_width_cm == g["track_cm"]
    assert drive.max_wheel_speed_cm_s == pytest.approx(m["max_wheel_rad_s"] * g["wheel_radius_cm"])
    assert drive.max_wheel_speed_cm_s > cfg["control"]["max_speed_cm_s"]  # the law's top speed is reachable
    assert 0.5 * math.hypot(BODY_LENGTH_CM, BODY_WIDTH_CM) <= g["body_radius_cm"]
    assert cfg["control"]["stale_ms"] + cfg["control"]["period_ms"] <= 500  # motors cut within the 0.5 s bar
    look = rover_looks([cfg])[0]
    assert (look.body_length_cm, look.body_width_cm) == (BODY_LENGTH_CM, BODY_WIDTH_CM)
    assert fleet_drive_model([cfg, rover_config("blue")]) == drive


def test_a_body_larger_than_the_firmware_assumes_is_refused() -> None:
    cfg = rover_config("red")
    cfg["geometry"] = {**cfg["geometry"], "body_radius_cm": 12.0}
    with pytest.raises(ConfigError, match=r"body_radius_cm 12 does not cover"):
        rover_looks([cfg])


def test_rovers_with_different_drives_cannot_share_one_world() -> None:
    other = rover_config("blue")
    other["geometry"] = {**other["geometry"], "track_cm": 15.0}
    with pytest.raises(ConfigError, match="differ"):
        fleet_drive_model([rover_config("red"), other])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kind": "square"}, "unknown experiment 'square'"),
        ({"kind": "triangle", "rovers": 2}, "triangle needs at least 3"),
        ({"kind": "line", "rovers": 13}, "--rovers must be 1-12"),
        ({"kind": "line", "frames": 0}, "--frames must be at least 1"),
    ],
)
def test_bad_experiments_are_refused_with_the_reason(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        LoopConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["circle", "diagonal"])
def test_scripted_paths_fit_the_rover_and_the_area(kind: str) -> None:
    drive = drive_model(rover_config("red"))
    plans = trajectory_plans(kind, 3, np.random.default_rng(0))
    for plan in plans:
        assert plan.max_wheel_speed_cm_s(drive.track_width_cm) <= drive.max_wheel_speed_cm_s
        for t in np.linspace(0.0, plan.duration_s, 200):
            pose = plan.sample(float(t))[0]
            assert 0.0 <= pose.x_cm <= AREA_WIDTH_CM and 0.0 <= pose.y_cm <= AREA_LENGTH_CM
    # no two bodies ever meet
    for t in np.linspace(0.0, max(p.duration_s for p in plans), 400):
        poses = np.array([[*(lambda q: (q.x_cm, q.y_cm, q.theta_rad))(p.sample(float(t))[0])] for p in plans])
        assert min_body_gap_cm(poses, BODY_LENGTH_CM, BODY_WIDTH_CM) > 5.0
