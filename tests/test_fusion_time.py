"""What a fused pose's time means: the capture instant, on the fuser's clock, of the newest measurement in it.

A pose published live can never be dated after it was published: whatever the boards' clocks, exposure phases,
latencies and trackers (one that leads the motion looks like a clock behind), ``arrival - t`` is a latency, and a
latency is never negative. A benchmark that reads a negative one has two clocks in it, not a fast system.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edge.fusion.core import Fuser, FusionSettings
from tests.support.fusion import Board, Path2D, Recording, circle, line, record

PATHS = {"r1": circle((400, 275), 120, 30), "r2": line((150, 150), (25, 8))}


def leading(paths: dict[str, Path2D], lead_s: float) -> dict[str, Path2D]:
    """The rovers as a tracker sees them that leads their motion by ``lead_s`` (negative: trails it)."""
    return {k: (lambda t, p=p: p(t + lead_s)) for k, p in paths.items()}


def two_boards(a: Board, b: Board, lead_s: float, seconds: float = 2.5) -> Recording:
    rec = record([a], PATHS, seconds)
    other = record([b], leading(PATHS, lead_s), seconds, seed=1)
    rec.boards.append(b)
    rec.frames |= other.frames
    rec.arrivals |= other.arrivals
    return rec


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    offsets_ms=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    phases_ms=st.tuples(st.floats(0, 33), st.floats(0, 33)),
    latencies_ms=st.tuples(st.floats(1, 40), st.floats(1, 40)),
    lead_ms=st.floats(-10, 10),
)
def test_a_live_pose_is_never_dated_after_it_is_published(
    offsets_ms: tuple[float, float], phases_ms: tuple[float, float], latencies_ms: tuple[float, float], lead_ms: float
) -> None:
    a = Board("a", (0, 0, 450, 550), offsets_ms[0] / 1e3, phases_ms[0] / 1e3, latency_s=latencies_ms[0] / 1e3)
    b = Board("b", (350, 0, 800, 550), offsets_ms[1] / 1e3, phases_ms[1] / 1e3, latency_s=latencies_ms[1] / 1e3)
    rec = two_boards(a, b, lead_ms / 1e3)
    fuser = Fuser(FusionSettings())
    published = 0
    ticks: dict[str, int] = {}
    for arrival, d in rec.in_arrival_order():
        for pose in fuser.add(d, now_s=arrival):
            # the fuser's clock is the true one here: the pose leaves at `arrival`
            assert arrival - pose.t_s >= -1e-9, (pose, arrival)
            # its frame: the nearest, or the next for a newer capture rounding onto the last pose's frame
            assert abs(pose.tick - pose.t_s * 30.0) <= 0.56 and pose.tick > ticks.get(pose.rover_id, -1), pose
            ticks[pose.rover_id] = pose.tick
            published += 1
    assert published > 140  # of 148 (2 rovers, 2.5 s at 30 fps): each frame's pose, whatever the boards' phases


@pytest.mark.parametrize("phases_ms", [(5.0, 5.25), (16.0, 16.0), (16.0, 16.25), (16.5, 16.75)])
def test_boards_capturing_near_a_half_frame_lose_no_pose(phases_ms: tuple[float, float]) -> None:
    """Both boards capture about half a frame after the shared clock's frame instants (16-17 ms at 30 fps): the
    clocks' corrections move their captures by a millisecond, across the half-frame and back, and a pose whose time
    rounded onto the last one's frame was dropped (111-135 of 148 poses published; 148 with captures at 5 ms).
    Every frame's pose comes out."""
    a = Board("a", (0, 0, 450, 550), 0.0, phases_ms[0] / 1e3, latency_s=0.001)
    b = Board("b", (350, 0, 800, 550), 0.0, phases_ms[1] / 1e3, latency_s=0.001)
    fuser = Fuser(FusionSettings())
    poses = [p for arrival, d in two_boards(a, b, 0.0).in_arrival_order() for p in fuser.add(d, now_s=arrival)]
    assert len(poses) == 148


@pytest.mark.parametrize("phases_ms", [(0.0, 16.0), (0.0, 16.5), (0.0, 17.0), (3.0, 19.5)])
def test_two_boards_seeing_the_whole_floor_half_a_frame_apart_keep_one_pose_a_frame_on_its_frame(
    phases_ms: tuple[float, float],
) -> None:
    """Both boards see every rover, their captures half a frame apart: two detections a frame period, each near the
    other's rounding. A rover gets at most one pose a frame, each on the frame nearest its time (within the 2 ms
    slack of a capture at the next frame's rounding): the frame never runs ahead of the clock (it did, by 25-30
    frames in 3 s, when any pose half a frame newer took the next frame)."""
    a = Board("a", (0, 0, 800, 550), 0.0, phases_ms[0] / 1e3, latency_s=0.001)
    b = Board("b", (0, 0, 800, 550), 0.0, phases_ms[1] / 1e3, latency_s=0.001)
    fuser = Fuser(FusionSettings())
    poses = [p for arrival, d in two_boards(a, b, 0.0, 3.0).in_arrival_order() for p in fuser.add(d, now_s=arrival)]
    for rover in PATHS:
        mine = [p for p in poses if p.rover_id == rover]
        assert 85 <= len(mine) <= 91  # frames 0-90 of 3 s
        assert all(abs(p.tick - p.t_s * 30.0) <= 0.5 + 0.002 * 30.0 + 1e-9 for p in mine), mine
        assert all(q.tick > p.tick for p, q in itertools.pairwise(mine))


@pytest.mark.parametrize("lead_ms", [-10.0, 10.0])
def test_a_tracker_that_leads_the_others_moves_no_capture_past_its_arrival(lead_ms: float) -> None:
    """Seven rovers circling in the overlap: ample evidence that b's measurements lead a's by 10 ms (or trail
    them), which the overlaps read as b's clock 10 ms behind a's. The arrival times say both clocks are right to a
    millisecond; the board the overlaps would put behind is held at its arrival bound, the other moves."""
    paths = {f"r{i}": circle((400, 60 + 70 * i), 30, 25, phase=i) for i in range(7)}
    a = Board("a", (0, 0, 450, 550), latency_s=0.002)
    b = Board("b", (350, 0, 800, 550), latency_s=0.002)
    rec = record([a], paths, 6.0)
    other = record([b], leading(paths, lead_ms / 1e3), 6.0, seed=1)
    rec.boards.append(b)
    rec.frames |= other.frames
    rec.arrivals |= other.arrivals
    fuser = Fuser(FusionSettings())
    ages = [arrival - p.t_s for arrival, d in rec.in_arrival_order() for p in fuser.add(d, now_s=arrival)]
    assert min(ages) >= -1e-9
    offsets = {k: e.offset_s for k, e in fuser.status(now_s=6.0).offsets.items()}
    behind, ahead = ("b", "a") if lead_ms > 0 else ("a", "b")
    assert offsets[behind] == pytest.approx(-0.001, abs=1e-6)  # ts - arrival: the floor
    # the other board takes up the difference (against its own arrival bound's pull: most of the 10 ms)
    assert 0.005 < offsets[ahead] - offsets[behind] < 0.013


def test_a_live_pose_is_dated_at_its_newest_capture_not_rounded_to_the_frame() -> None:
    """A board exposing 20 ms after the frame instants: its poses carry its capture instants (the latency a rover
    sees is the real one), not the next frame's instant 13 ms in the future."""
    board = Board("a", (0, 0, 800, 550), clock_offset_s=0.0, phase_s=0.020, latency_s=0.004)
    rec = record([board], PATHS, 2.0)
    fuser = Fuser(FusionSettings())
    ages = [arrival - p.t_s for arrival, d in rec.in_arrival_order() for p in fuser.add(d, now_s=arrival)]
    assert len(ages) > 100
    # the arrival bound puts the board's clock 1 ms ahead (its send stamp is 1 ms before arrival): 4 ms to 3 ms
    assert min(ages) == pytest.approx(0.003, abs=0.0011) and max(ages) == pytest.approx(0.004, abs=0.0011)


def test_a_recording_is_fused_onto_the_frames_of_the_shared_clock() -> None:
    board = Board("a", (0, 0, 800, 550), phase_s=0.010)
    rec = record([board], PATHS, 1.0)
    fuser = Fuser(replace(FusionSettings(), pose_time="frame"))
    poses = [p for d in rec.frames["a"] for p in fuser.add(d)]
    assert poses and all(p.t_s == pytest.approx(p.tick / 30.0) for p in poses)


# -- the live benchmark's boards ---------------------------------------------------------------------------------
def _bench():  # type: ignore[no-untyped-def]
    from tests.conftest import benchmark_module

    return benchmark_module("bench_fusion")


def test_the_benchmarks_boards_show_one_world_instant_at_one_grab_time_wherever_they_started() -> None:
    """The replayed boards of the live benchmark: a board that started (or fell behind and skipped) later shows, at
    grab tick k, the same recorded frame as every other; the recording plays forwards and back without a jump.
    (Each board once counted its own frames from its own start: boards started a second apart showed the fuser
    rovers 30 frames apart at one grab time, and the latencies came out negative.)"""
    bench = _bench()
    k0, frames = 1000, 300
    for k in range(k0, k0 + 2000):
        i = bench.replay_index(k, k0, frames)
        assert 0 <= i < frames
        assert abs(i - bench.replay_index(k + 1, k0, frames)) == 1  # forwards or back, never a teleport
    assert [bench.replay_index(k, k0, frames) for k in (k0, k0 + 299, k0 + 300, k0 + 598)] == [0, 299, 298, 0]


def test_the_benchmark_counts_a_negative_latency_as_a_clock_error() -> None:
    stats = _bench().latency_stats([3.0, 5.0, -2.0])
    assert stats["negative"] == 1 and stats["min"] == -2.0
