"""The per-rover constant-velocity filter: velocity, spike rejection, restart after a real jump, no lag in turns."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge import filtering
from edge.filtering import (
    CLEAR_VELOCITY_SIGMAS,
    SMALL_MARKER_POWER,
    SMALL_MARKER_PX,
    ConstantVelocityFilter,
    FilterSettings,
    HeadingFilter,
    checked_axis,
    heading_sigma_rad,
    one_colour_heading,
)

DT = 1.0 / 30.0
R = np.eye(2) * 0.04  # 0.2 cm measurement sigma


def run(path, settings=None, noise_cm=0.2, seed=0):
    """Filter a path ``t -> (x, y)``; returns the filter and the per-frame estimate errors."""
    rng = np.random.default_rng(seed)
    f = ConstantVelocityFilter(settings or FilterSettings(), path(0.0), R)
    errors = []
    for k in range(1, 300):
        t = k * DT
        f.predict(DT)
        truth = np.array(path(t))
        f.update(truth + rng.normal(0.0, noise_cm, 2), R)
        errors.append(float(np.hypot(*(np.array(f.position) - truth))))
    return f, np.array(errors)


def test_velocity_is_unknown_until_two_measurements():
    f = ConstantVelocityFilter(FilterSettings(), (10.0, 20.0), R)
    assert f.velocity is None
    f.predict(DT)
    f.update(np.array([10.5, 20.0]), R)
    assert f.velocity is not None


@pytest.mark.parametrize(("vx", "vy"), [(20.0, 0.0), (0.0, -35.0), (12.0, 16.0)])
def test_straight_motion_gives_the_velocity(vx, vy):
    f, errors = run(lambda t: (50.0 + vx * t, 300.0 + vy * t))
    assert f.velocity == pytest.approx((vx, vy), abs=1.5)
    assert errors[30:].mean() < 0.2  # smoother than the 0.2 cm measurements


def test_a_single_spike_is_rejected_and_the_state_kept():
    f, _ = run(lambda t: (100.0 + 10.0 * t, 100.0))
    before = f.position
    f.predict(DT)
    predicted = f.position
    assert not f.update(np.array([before[0] + 25.0, before[1]]), R)
    assert f.position == predicted
    assert f.rejected == 1
    f.predict(DT)
    assert f.update(np.array([predicted[0] + 10.0 * DT, predicted[1]]), R)


def test_a_real_jump_seen_again_restarts_the_filter_there():
    f, _ = run(lambda t: (100.0, 100.0))
    for _ in range(2):
        f.predict(DT)
        f.update(np.array([160.0, 40.0]), R)
    assert f.position == pytest.approx((160.0, 40.0), abs=0.01)


def test_inconsistent_outliers_never_restart_the_filter():
    f, _ = run(lambda t: (100.0, 100.0))
    for k in range(6):
        f.predict(DT)
        f.update(np.array([160.0 + 40.0 * (k % 2), 40.0 + 50.0 * (k % 2)]), R)
    assert f.position == pytest.approx((100.0, 100.0), abs=0.5)


def circle(radius_cm, speed_cm_s):
    w = speed_cm_s / radius_cm
    return lambda t: (200.0 + radius_cm * math.cos(w * t), 250.0 + radius_cm * math.sin(w * t))


@pytest.mark.parametrize(("radius", "speed"), [(40.0, 30.0), (80.0, 40.0), (150.0, 25.0)])
def test_a_turning_rover_is_followed_without_lag(radius, speed):
    _, errors = run(circle(radius, speed))
    assert errors[30:].mean() < 0.3
    assert np.percentile(errors[30:], 95) < 0.6


def test_fading_on_surprising_innovations_is_what_removes_the_lag():
    stiff = FilterSettings(accel_sigma_cm_s2=10.0, max_fade=1.0)
    fading = FilterSettings(accel_sigma_cm_s2=10.0)
    _, lagging = run(circle(20.0, 30.0), stiff)
    _, following = run(circle(20.0, 30.0), fading)
    assert following[30:].mean() < 0.5 * lagging[30:].mean()


def test_a_manoeuvre_is_not_mistaken_for_spikes():
    f = ConstantVelocityFilter(FilterSettings(), (100.0, 100.0), R)
    for k in range(1, 90):  # straight at 30 cm/s, then a sudden stop
        f.predict(DT)
        x = 100.0 + 30.0 * min(k, 45) * DT
        assert f.update(np.array([x, 100.0]), R)
    assert f.rejected == 0
    assert f.velocity == pytest.approx((0.0, 0.0), abs=1.0)


@pytest.mark.parametrize(("radius", "speed"), [(80.0, 30.0), (100.0, 20.0)])
def test_heading_from_the_filter_velocity_is_tangent_to_a_circle(radius, speed):
    path = circle(radius, speed)
    w = speed / radius
    rng = np.random.default_rng(3)
    f = ConstantVelocityFilter(FilterSettings(), path(0.0), R)
    errors = []
    for k in range(1, 300):
        t = k * DT
        f.predict(DT)
        f.update(np.array(path(t)) + rng.normal(0.0, 0.2, 2), R)
        vx, vy = f.velocity
        tangent = math.atan2(math.cos(w * t), -math.sin(w * t))
        errors.append(abs(math.degrees(math.remainder(math.atan2(vy, vx) - tangent, math.tau))))
    assert np.median(errors[30:]) < 3.0


def test_position_uncertainty_grows_while_coasting():
    f, _ = run(lambda t: (100.0, 100.0))
    sigma = f.position_sigma_cm
    for _ in range(10):
        f.predict(DT)
    assert f.position_sigma_cm > 2.0 * sigma


@pytest.mark.parametrize(
    ("axis_deg", "velocity", "last_deg", "expected_deg"),
    [
        (30.0, (10.0, 6.0), None, 30.0),  # moving along the axis
        (30.0, (-10.0, -6.0), None, -150.0),  # moving the other way: the axis points back
        (-150.0, (10.0, 6.0), 100.0, 30.0),  # the motion decides while moving, not the last heading
        (95.0, (0.5, 0.0), 80.0, 95.0),  # standing (turning on the spot): the end nearest the last heading
        (95.0, None, -80.0, -85.0),
        (95.0, None, None, None),  # never moved: no front known
        (None, (0.0, 12.0), 10.0, 90.0),  # no axis (a square marker): the direction of motion
        (None, (0.5, 0.0), 10.0, None),
    ],
)
def test_a_one_colour_markers_heading_is_its_axis_pointed_by_the_motion(axis_deg, velocity, last_deg, expected_deg):
    from edge.filtering import axis_heading

    got = axis_heading(
        None if axis_deg is None else math.radians(axis_deg),
        velocity,
        None if last_deg is None else math.radians(last_deg),
        3.0,
    )
    if expected_deg is None:
        assert got is None
    else:
        assert got is not None
        assert math.degrees(math.remainder(got - math.radians(expected_deg), math.tau)) == pytest.approx(0.0, abs=1e-9)


def _axis_deg(axis_rad: float) -> float:
    return math.degrees(math.remainder(axis_rad, math.pi))


def _driving(deg: float, speed: float = 15.0) -> tuple[float, float]:
    return speed * math.cos(math.radians(deg)), speed * math.sin(math.radians(deg))


def test_coherent_edges_give_the_axis_whatever_the_motion_says():
    """Edges that show the rectangle clearly are sharper than the filter's direction of motion (which lags in a
    turn): taken as they are, even 40 degrees from it."""
    assert _axis_deg(checked_axis(math.radians(30.0), 0.6, _driving(70.0))) == pytest.approx(30.0)


@pytest.mark.parametrize("coherence", [0.35, 0.8])
def test_the_motion_picks_the_long_one_of_the_edges_two_directions(coherence):
    """The edges give the orientation modulo 90 degrees and the blob's elongation picks the long axis; on a
    far-side smudge it picked the short one in one frame of three. A driving rover's motion picks it instead."""
    assert _axis_deg(checked_axis(math.radians(95.0), coherence, _driving(6.0))) == pytest.approx(5.0)
    assert _axis_deg(checked_axis(math.radians(5.0), coherence, _driving(6.0))) == pytest.approx(5.0)


def test_a_blobs_axis_gives_way_to_the_direction_of_motion_while_the_rover_drives():
    """The blob's second moments (coherence 0) were 20-25 degrees off for seconds on a far-side smudge; a driving
    differential drive's direction of motion is its axis (modulo pi: driving towards 100 degrees is the axis -80)."""
    assert _axis_deg(checked_axis(math.radians(-58.0), 0.0, _driving(100.0))) == pytest.approx(-80.0)
    assert _axis_deg(checked_axis(math.radians(-78.0), 0.0, _driving(100.0))) == pytest.approx(-80.0)


@pytest.mark.parametrize(("axis_deg", "expected_deg"), [(45.0, 45.0), (25.0, 25.0), (62.0, 40.0), (-5.0, 40.0)])
def test_weakly_coherent_edges_far_from_the_motion_give_way_to_it(axis_deg, expected_deg):
    """Weak edges (coherence 0.3-0.5) within 20 degrees of the direction of motion are kept (they are sharper than
    it where they are right); farther off they pointed 30 degrees wrong now and then, and the motion stands in."""
    assert _axis_deg(checked_axis(math.radians(axis_deg), 0.4, _driving(40.0))) == pytest.approx(expected_deg)


@pytest.mark.parametrize("velocity", [None, (0.0, 0.0), _driving(40.0, speed=3.0)])
def test_standing_or_crawling_the_measurement_is_all_there_is(velocity):
    """Standing, turning on the spot or crawling (the filter's direction scatters at a few cm/s), even the blob's
    axis is kept: the motion says nothing about the axis then."""
    assert _axis_deg(checked_axis(math.radians(-58.0), 0.0, velocity)) == pytest.approx(-58.0)


def test_the_heading_filter_keeps_one_frames_wrong_axis_from_the_heading_and_follows_a_turn() -> None:
    f = HeadingFilter()
    rng = np.random.default_rng(5)
    worst_spike, worst_turn = 0.0, 0.0
    for k in range(300):
        t = k / 30.0
        truth = 0.3 + (1.0 * (t - 5.0) if t > 5.0 else 0.0)  # straight for 5 s, then a turn at 1 rad/s
        z = truth + math.radians(1.0) * rng.standard_normal()
        coherence = 0.7
        if k % 25 == 0:  # a coherent-looking but weak edge 15 degrees off, now and then
            z, coherence = truth + math.radians(15.0), 0.4
        got = f.update(z, heading_sigma_rad(coherence), t)
        err = abs(math.degrees(math.remainder(got - truth, math.tau)))
        if k % 25 == 0 and k > 30:
            worst_spike = max(worst_spike, err)
        if t > 5.5 and k % 25 != 0:
            worst_turn = max(worst_turn, err)
    assert worst_spike < 8.0  # the 15 degree frames come through at about half or less
    assert worst_turn < 3.0  # half a second into a 1 rad/s turn it follows without lag


def test_the_heading_filter_starts_afresh_when_the_rover_reverses() -> None:
    f = HeadingFilter()
    for k in range(30):
        f.update(0.5, math.radians(1.5), k / 30.0)
    assert f.update(0.5 + math.pi, math.radians(1.5), 1.0) == pytest.approx(0.5 + math.pi)


def test_a_direction_of_motion_far_from_the_heading_is_ignored_not_taken() -> None:
    f = HeadingFilter()
    for k in range(30):
        f.update(0.5, math.radians(1.5), k / 30.0)
    # a rover pushed sideways: its motion 90 degrees off its axis
    assert f.update(0.5 + math.pi / 2, math.radians(5.0), 1.0, gate_rad=math.radians(30.0)) == pytest.approx(0.5)
    assert f.update(0.5, math.radians(1.5), 1.0 + 1 / 30) == pytest.approx(0.5, abs=1e-6)


@pytest.mark.parametrize("noise_factor", [1.0, 2.0])
def test_a_standing_rovers_velocity_has_no_direction_even_when_its_camera_is_noisier_than_told(
    noise_factor: float,
) -> None:
    """A one-colour marker's front is taken from the direction of motion. A standing rover's filtered velocity is
    its measurements' noise, a few cm/s in a random direction right after the filter starts, and taken as motion it
    gave a standing rover a heading that was 180 degrees off half the time (the family's harsh cameras: 33-152 rover
    frames a run, for up to 3.5 s, until the rover drove off). ``clear_velocity`` gives none for a standing rover,
    also where the measurements scatter twice as much as the filter was told (the far side of a harsh stream)."""
    rng = np.random.default_rng(3)
    f = ConstantVelocityFilter(FilterSettings(), (100.0, 200.0), R)
    clear = []
    for _ in range(1, 300):
        f.predict(DT)
        f.update(np.array([100.0, 200.0]) + rng.normal(0.0, 0.2 * noise_factor, 2), R)
        clear.append(f.clear_velocity(CLEAR_VELOCITY_SIGMAS) is not None)
    assert f.velocity is not None  # there is a velocity estimate ...
    assert not any(clear[:30])  # ... but none with a direction while the filter starts
    assert sum(clear) <= 0.02 * len(clear)  # and hardly ever after


@pytest.mark.parametrize("speed", [10.0, 25.0])
def test_a_driving_rovers_velocity_is_clear_once_the_filter_has_settled(speed: float) -> None:
    f, _ = run(lambda t: (50.0 + speed * t * 0.6, 300.0 + speed * t * 0.8))
    clear = f.clear_velocity(CLEAR_VELOCITY_SIGMAS)
    assert clear is not None and clear == pytest.approx((0.6 * speed, 0.8 * speed), abs=1.5)


def test_a_small_marker_s_edges_count_for_less_than_a_large_one_s_of_the_same_coherence() -> None:
    """Coherence says how clearly the edges show a rectangle, not how many pixels show it."""
    for coherence in (0.4, 0.8):
        large = heading_sigma_rad(coherence)
        assert heading_sigma_rad(coherence, SMALL_MARKER_PX * 2.0) == large
        assert heading_sigma_rad(coherence, SMALL_MARKER_PX) == pytest.approx(large)
        assert heading_sigma_rad(coherence, SMALL_MARKER_PX / 4.0) == pytest.approx(large * 4.0**SMALL_MARKER_POWER)
    # the blob's axis or the motion standing in for edges: their own scatter, whatever the size
    assert heading_sigma_rad(0.0, 100.0) == heading_sigma_rad(0.0)


def _filter_moving(velocity: tuple[float, float], cov: tuple[float, float, float]) -> ConstantVelocityFilter:
    f = ConstantVelocityFilter(FilterSettings(), (0.0, 0.0), np.eye(2))
    f.x = [0.0, 0.0, *velocity]
    f.p[10], f.p[11], f.p[14], f.p[15] = cov[0], cov[1], cov[1], cov[2]
    return f


def test_the_direction_of_motion_s_scatter_is_the_velocity_s_across_it_over_the_speed() -> None:
    # 20 cm/s along x, velocity sigma 1 cm/s along and 2 cm/s across: 0.1 rad
    assert _filter_moving((20.0, 0.0), (1.0, 0.0, 4.0)).direction_sigma_rad() == pytest.approx(0.1)
    # the same turned by 90 degrees
    assert _filter_moving((0.0, -20.0), (4.0, 0.0, 1.0)).direction_sigma_rad() == pytest.approx(0.1)
    # turned by 45 degrees, the covariance with it
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    cov = (c * c * 1.0 + s * s * 4.0, c * s * (1.0 - 4.0), s * s * 1.0 + c * c * 4.0)
    assert _filter_moving((20.0 * c, 20.0 * s), cov).direction_sigma_rad() == pytest.approx(0.1)
    assert _filter_moving((0.0, 0.0), (1.0, 0.0, 1.0)).direction_sigma_rad() == math.inf


def _turning_rover_headings(
    marker_px: float, motion_sigma_rad: float, motion_noise_deg: float, axis_noise_deg: float = 6.0, coherence=0.6
) -> np.ndarray:
    """Errors (deg) of one_colour_heading for a rover driving a steady 20 deg/s arc at 20 cm/s for 10 s, its edges'
    axis (of ``coherence``) scattered by ``axis_noise_deg`` (6: a far-side marker's) and its filter's direction of
    motion by ``motion_noise_deg``."""
    rng = np.random.default_rng(11)
    heading = HeadingFilter()
    theta, errors = None, []
    for k in range(300):
        t = k / 30.0
        truth = 0.4 + math.radians(20.0) * t
        axis = truth + math.radians(axis_noise_deg) * rng.standard_normal()
        motion = truth + math.radians(motion_noise_deg) * rng.standard_normal()
        velocity = (20.0 * math.cos(motion), 20.0 * math.sin(motion))
        theta = one_colour_heading(heading, axis, coherence, velocity, theta, 3.0, t, marker_px, motion_sigma_rad)
        assert theta is not None
        if k >= 30:
            errors.append(abs(math.degrees(math.remainder(theta - truth, math.tau))))
    return np.asarray(errors)


def test_a_small_marker_s_scattered_axes_move_its_heading_less() -> None:
    """A far-side marker (200 px) whose coherent-looking edges scatter by 6 degrees, and its direction of motion
    by 3: weighed by its size the heading leans on the motion and its own turn, and is nearer the truth."""
    as_large = _turning_rover_headings(math.inf, 0.0, 3.0)
    by_size = _turning_rover_headings(200.0, 0.0, 3.0)
    assert np.percentile(by_size, 95) < 0.8 * np.percentile(as_large, 95)
    assert np.median(by_size) < np.median(as_large)


def test_a_scattered_direction_of_motion_moves_the_heading_less_when_its_filter_says_so() -> None:
    """A direction of motion scattered by 20 degrees (a far-side rover's position noise at a crawl) and a large
    marker's clearly coherent edges (1.5 degrees): told its scatter, the heading follows the edges; told 5 degrees,
    the motion pulls it about."""
    told = _turning_rover_headings(math.inf, math.radians(20.0), 20.0, 1.5)
    untold = _turning_rover_headings(math.inf, 0.0, 20.0, 1.5)
    assert np.percentile(told, 95) < 0.8 * np.percentile(untold, 95)
    assert np.median(told) < 0.8 * np.median(untold)


def test_edges_scattering_more_than_they_claim_are_widened_by_their_own_innovations(monkeypatch) -> None:
    """A large marker's coherent edges (claimed 1.5 degrees) that scatter by 6 (a harsh stream's far side, where
    size alone does not tell): the filter learns it from how far they fall from its prediction, and leans on the
    motion and its turn; edges as good as they claim are not widened."""
    adapted = _turning_rover_headings(math.inf, 0.0, 3.0, 6.0)
    monkeypatch.setattr(filtering, "SCATTER_MAX", 1.0)
    fixed = _turning_rover_headings(math.inf, 0.0, 3.0, 6.0)
    assert np.percentile(adapted, 95) < 0.8 * np.percentile(fixed, 95)

    honest = HeadingFilter()
    rng = np.random.default_rng(3)
    for k in range(150):
        honest.update(0.4 + math.radians(1.5) * rng.standard_normal(), math.radians(1.5), k / 30.0)
    assert honest.scatter < 1.5
    wild = HeadingFilter()
    for k in range(150):
        wild.update(0.4 + math.radians(6.0) * rng.standard_normal(), math.radians(1.5), k / 30.0)
    assert wild.scatter > 4.0
