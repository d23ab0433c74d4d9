"""Centres referred to the marker's fitted edges (edge.centre_offsets, the ``edge_offsets`` tracker setting): the
fits' samples, the offset they give across the floor, where the fits run (in the loop, in a worker process that
can fail, in a pool of workers on the loop's schedule), and the pipeline's centres on a 4:2:0 stream with and without
them."""

from __future__ import annotations

import json
import logging
import math
import multiprocessing
import os
import select
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from edge.camera import paper_camera
from edge.centre_offsets import (
    MAX_OFFSET_CM,
    MAX_OFFSET_PX,
    MIN_SAMPLES,
    STALL_FRAMES,
    TRUST_CM,
    CentreOffsets,
    EdgeJob,
    EdgeSample,
    InlineFits,
    OffsetMap,
    fit_offset,
    image_px,
)
from edge.coverage import coverage_weights
from edge.fit_worker import ProcessFits
from edge.pooled_fits import PooledFits
from edge.sim.effects import Compression, Effects, Optics
from edge.sim.render import Renderer
from edge.sim.scene import GREEN_BGR, RED_BGR, RoverLook, Scene
from edge.sim.world import RoverState, WorldState
from edge.tracker_config import RoverConfig, TrackerConfig
from edge.trackers.base import CameraPlaneMapping, Measurement, PlaneGrid
from edge.trackers.factory import build_tracker
from edge.trackers.plane import world_blob
from edge.tracking import Frame
from tests.conftest import REPO

SIZE_CM = (21.5, 16.8)
BLACK = (0.035, 0.034, 0.032)
STREAM = Effects(
    auto_exposure=None, noise=None, motion_blur=False, optics=Optics(0.9), compression=Compression(90, "4:2:0")
)


@pytest.fixture(scope="module")
def grid() -> PlaneGrid:
    return PlaneGrid(CameraPlaneMapping(paper_camera()), (1280, 720))


def _job(
    grid: PlaneGrid, pose: tuple[float, float, float], color=GREEN_BGR, half_px: int = 60
) -> tuple[EdgeJob, tuple]:
    """A 4:2:0 frame's window around a rover on a black body at ``pose``, its fast (coverage) centre, the job."""
    look = RoverLook("r", color, body_bgr=BLACK)
    image = Renderer(paper_camera(), Scene((look,)), STREAM).render(
        WorldState(0.0, (RoverState("r", *pose, 0, 0, 0),)), 0
    )
    x, y, th = pose
    uv = paper_camera().project(np.array([[x, y, 13.0]]))[0]
    x0, y0 = int(uv[0]) - half_px, int(uv[1]) - half_px
    rows, cols = slice(y0, y0 + 2 * half_px), slice(x0, x0 + 2 * half_px)
    xy = grid.xy_cm[:, rows, cols]
    along = (xy[0] - x) * math.cos(th) + (xy[1] - y) * math.sin(th)
    across = (xy[1] - y) * math.cos(th) - (xy[0] - x) * math.sin(th)
    core = (np.abs(along) < SIZE_CM[0] / 2) & (np.abs(across) < SIZE_CM[1] / 2)
    roi = np.ascontiguousarray(image[rows, cols])
    blob = world_blob(coverage_weights(roi, core, 2, pure=core), (x0, y0), grid)
    assert blob is not None
    job = EdgeJob(0, 0, roi, np.asarray(xy, np.float64), (blob.x_cm, blob.y_cm), th, SIZE_CM)
    return job, pose


@pytest.mark.slow
@pytest.mark.parametrize("pose", [(205.0, 330.0, 2.6), (120.0, 210.0, 1.2)])
def test_a_fit_of_a_4_2_0_window_gives_the_offset_that_puts_the_centre_on_the_marker(grid, pose):
    job, (x, y, _) = _job(grid, pose)
    sample = fit_offset(job)
    assert sample is not None
    fast_error = math.hypot(job.centre_cm[0] - x, job.centre_cm[1] - y)
    fitted = (job.centre_cm[0] + sample.offset_cm[0], job.centre_cm[1] + sample.offset_cm[1])
    fitted_error = math.hypot(fitted[0] - x, fitted[1] - y)
    assert fast_error > 0.1  # the stream's chroma spread moved the fast centre
    assert fitted_error < 0.5 * fast_error and fitted_error < 0.08
    assert sample.xy_cm == job.centre_cm and sample.index == job.index


@pytest.mark.slow
def test_a_window_too_small_to_show_the_band_beyond_the_edges_gives_no_sample(grid):
    job, _ = _job(grid, (200.0, 300.0, 0.3), half_px=13)
    assert fit_offset(job) is None


@pytest.mark.slow
def test_a_fit_that_lands_far_from_the_fast_centre_is_no_sample(grid):
    job, _ = _job(grid, (200.0, 300.0, 0.3))
    # the fast centre 4 cm off: the window's sides are sampled where the marker is not
    assert fit_offset(replace(job, centre_cm=(job.centre_cm[0] + 4.0, job.centre_cm[1]))) is None


@pytest.mark.slow
def test_on_the_far_side_a_fit_more_than_a_centimetre_but_under_a_pixel_off_is_a_sample(grid):
    """On the far side a pixel spans 2.2 cm along the view: a fast centre 1.5 cm off there is 0.67 pixels off, and a
    fit that finds it is an offset, not a failure (a purple marker on a white body, 4:2:0 q60, was 1.5-2 cm off for
    three seconds while a 1 cm limit refused every fit that said so); 3 cm (1.3 pixels) off is still a failed fit."""
    job, _ = _job(grid, (105.0, 531.0, 3.0))
    base = fit_offset(job)
    assert base is not None
    off = replace(job, centre_cm=(job.centre_cm[0], job.centre_cm[1] + 1.5))
    assert image_px(job.xy_cm, off.centre_cm, (0.0, 1.5)) < MAX_OFFSET_PX
    sample = fit_offset(off)
    assert sample is not None
    assert sample.offset_cm == pytest.approx((base.offset_cm[0], base.offset_cm[1] - 1.5), abs=0.25)
    assert math.hypot(*sample.offset_cm) > MAX_OFFSET_CM
    assert fit_offset(replace(job, centre_cm=(job.centre_cm[0], job.centre_cm[1] + 3.0))) is None


def test_a_step_on_the_plane_is_measured_in_the_pixels_it_spans_where_it_is(grid):
    for x, y in ((105.0, 531.0), (200.0, 60.0)):
        u, v = (int(c) for c in paper_camera().project(np.array([[x, y, 13.0]]))[0])
        xy = np.asarray(grid.xy_cm[:, v - 10 : v + 10, u - 10 : u + 10], np.float64)
        # one pixel down the image from the nearest pixel's centre spans exactly one pixel
        r, c = np.unravel_index(int(np.argmin((xy[0] - x) ** 2 + (xy[1] - y) ** 2)), xy.shape[1:])
        step = xy[:, r + 1, c] - xy[:, r, c]
        assert image_px(xy, (x, y), (float(step[0]), float(step[1]))) == pytest.approx(1.0, abs=1e-9)
    far = np.asarray(grid.xy_cm[:, 105:125, 519:539], np.float64)
    near = np.asarray(grid.xy_cm[:, 523:543, 640:660], np.float64)
    # a centimetre along the view spans under half a pixel on the far side and nearly two on the near side
    assert image_px(far, (105.0, 531.0), (0.0, 1.0)) < 0.5 < 1.5 < image_px(near, (200.0, 60.0), (0.0, 1.0))
    assert image_px(far[:, :1, :], (105.0, 531.0), (0.0, 1.0)) == math.inf  # one row: no scale


def _sample(x: float, y: float, dx: float, dy: float, frame: int = 0) -> EdgeSample:
    return EdgeSample(0, frame, (x, y), (dx, dy))


def test_a_rovers_first_samples_move_its_centre_in_part_then_the_near_samples_count_most():
    offsets = OffsetMap()
    assert offsets.offset(0.0, 0.0) is None
    for k in range(MIN_SAMPLES - 1):
        offsets.add(_sample(0.0, 5.0 * k, 0.3, 0.0, k))
        dx, dy = offsets.offset(0.0, 0.0) or (math.nan, math.nan)
        # a share of the offset, as many thirds as it has samples, less the fits' own error
        assert dx == pytest.approx(0.3 * (k + 1) / MIN_SAMPLES - TRUST_CM, abs=1e-9) and dy == 0.0
    offsets.add(_sample(0.0, 10.0, 0.3, 0.0))
    for k in range(3):
        offsets.add(_sample(300.0, 5.0 * k, 0.1, 0.15, k))
    here = offsets.offset(0.0, 0.0)
    there = offsets.offset(300.0, 0.0)
    assert here is not None and there is not None
    assert here[0] > 0.18 and there[0] < 0.12  # each place its own offset, shrunk a little to the median
    assert there[1] > 0.06 and abs(here[1]) < 0.03


def test_samples_taken_at_one_place_count_as_one_and_do_not_outvote_the_others():
    # a rover waiting at its start, sampled five times where a tile's joint ran along its far edge, then four
    # samples as it drove on: the five repeat one error, and count as one sample among five places
    burst, once = OffsetMap(), OffsetMap()
    for k in range(5):
        burst.add(_sample(340.0 + 0.2 * k, 495.0, 0.0, 0.2, k))
    once.add(_sample(340.0, 495.0, 0.0, 0.2))
    for k, (x, dy) in enumerate(((310.0, -0.35), (290.0, -0.25), (270.0, -0.2), (245.0, -0.1))):
        burst.add(_sample(x, 500.0, 0.0, dy, 10 + k))
        once.add(_sample(x, 500.0, 0.0, dy, 10 + k))
    _, dy = burst.offset(245.0, 500.0) or (math.nan, math.nan)
    _, dy_once = once.offset(245.0, 500.0) or (math.nan, math.nan)
    assert dy < -0.05 and dy == pytest.approx(dy_once, abs=0.01)  # as if the place had given one sample, not five


def test_an_offset_within_the_fits_own_error_is_not_applied_and_a_larger_one_less_that_error():
    small, large = OffsetMap(), OffsetMap()
    for k in range(5):
        small.add(_sample(100.0, 100.0, 0.6 * TRUST_CM, 0.0, k))
        large.add(_sample(100.0, 100.0, 0.0, -0.3, k))
    assert small.offset(100.0, 100.0) == (0.0, 0.0)
    dx, dy = large.offset(100.0, 100.0) or (math.nan, math.nan)
    assert dx == pytest.approx(0.0, abs=1e-12) and dy == pytest.approx(-0.3 + TRUST_CM, abs=1e-9)


def test_a_sample_far_from_the_rovers_others_is_not_used():
    offsets = OffsetMap()
    for k in range(6):
        offsets.add(_sample(100.0 + k, 100.0, 0.0, -0.2, k))
    offsets.add(_sample(100.0, 100.0, 0.9, 0.9))  # another rover in the band beyond an edge, a fit run off
    dx, dy = offsets.offset(100.0, 100.0) or (math.nan, math.nan)
    assert dx == pytest.approx(0.0, abs=1e-9) and dy == pytest.approx(-0.2 + TRUST_CM, abs=1e-9)


@pytest.mark.slow
def test_fits_in_the_loop_come_back_as_late_as_from_a_worker_and_no_more_often_than_set(grid):
    job, _ = _job(grid, (150.0, 250.0, 1.0))
    fits = InlineFits(every_frames=10, delay_frames=15)
    assert fits.ready(0)
    fits.submit(replace(job, frame=0))
    assert not fits.ready(9) and fits.ready(10) and fits.ready(1, hurry=True)
    assert fits.collect(14) == []
    (sample,) = fits.collect(15)
    assert sample == fit_offset(job)
    assert fits.collect(16) == []


def test_the_rover_sampled_longest_ago_is_next_and_a_rover_without_enough_samples_first():
    offsets = CentreOffsets(InlineFits(every_frames=10, delay_frames=0))
    offsets._turn = {0: 5, 1: 3, 2: 8}
    assert offsets.pick(20, [0, 1, 2]) == 1  # none has samples yet: the oldest job
    for k in range(MIN_SAMPLES):
        offsets.maps.setdefault(1, OffsetMap()).add(_sample(0, 0, 0, 0, k))
    assert offsets.pick(20, [0, 1, 2]) == 0  # rover 1 has its samples: the others first
    assert offsets.pick(20, []) is None


class _Taken:
    """Fits that are always ready and keep the jobs handed over (the schedule is under test, not the fit)."""

    def __init__(self) -> None:
        self.jobs: list[EdgeJob] = []

    def ready(self, frame: int, hurry: bool = False) -> bool:
        return True

    def submit(self, job: EdgeJob) -> None:
        self.jobs.append(job)

    def collect(self, frame: int) -> list[EdgeSample]:
        return []

    def close(self) -> None:
        pass


def test_a_rover_whose_window_cannot_go_passes_its_turn_and_does_not_hold_the_fits(grid):
    """Held for a rover whose edges do not show its axis (a magenta marker on wood: coherence under 0.5 in 92 % of a
    clip's frames) or that is not measured (hidden), the fits idled: eight rovers' third samples came 70 frames
    late."""
    fits = _Taken()
    offsets = CentreOffsets(fits)
    tracks = [
        SimpleNamespace(
            index=i, filter=None, offset_cm=(0.0, 0.0), config=SimpleNamespace(id=f"r{i}", front_color_bgr=None)
        )
        for i in range(3)
    ]
    for tr in tracks:
        tr.filter = SimpleNamespace(position=(0.0, 0.0), shift=lambda dx, dy: None)
    window = SimpleNamespace(box=(0, 0, 4, 4), raw=np.zeros((4, 4, 3), np.uint8), bgr=None)

    def measured(coherence: float) -> Measurement:
        return Measurement((10.0, 20.0), (2.0, 2.0), 360.0, 100.0, 1.0, 0.0, 1.3, False, axis_coherence=coherence)

    offsets.start_frame(0, tracks)  # rover 0's turn; its edges do not show the axis
    for tr, coherence in zip(tracks, (0.3, 0.9, 0.9), strict=True):
        offsets.corrected(window, measured(coherence), tr, grid, SIZE_CM)
    assert fits.jobs == []
    offsets.start_frame(1, tracks)  # rover 1's turn; it is not measured this frame
    assert fits.jobs == []
    offsets.start_frame(2, tracks)  # rover 2's turn: its window goes
    for tr in tracks:
        offsets.corrected(window, measured(0.9), tr, grid, SIZE_CM)
    assert [job.index for job in fits.jobs] == [2]
    offsets.start_frame(3, tracks)  # then rover 0's again, whose turn passed first
    for tr in tracks:
        offsets.corrected(window, measured(0.9), tr, grid, SIZE_CM)
    assert [job.index for job in fits.jobs] == [2, 0]


@pytest.mark.slow
def test_fits_in_a_worker_process_give_the_same_sample_and_a_fit_that_raises_costs_nothing(grid):
    job, _ = _job(grid, (150.0, 250.0, 1.0))
    fits = ProcessFits(every_frames=1)
    try:
        fits.submit(job)
        assert not fits.ready(0)  # one at a time
        assert fits.wait(120.0)
        assert fits.collect(1) == [fit_offset(job)]
        broken = replace(job, frame=2, raw=np.zeros((4, 4), np.uint8))  # a job the fit cannot read: raises there
        assert fits.ready(2)
        fits.submit(broken)
        assert fits.wait(120.0)
        assert fits.collect(3) == [] and fits.failed == 1
        fits.submit(replace(job, frame=4))  # the worker still serves
        assert fits.wait(120.0)
        assert len(fits.collect(5)) == 1
    finally:
        fits.close()


def _still_rover_frames(n: int) -> list[np.ndarray]:
    """``n`` frames of a 4:2:0 q75 stream (noise on) of a red and a green rover on black bodies, standing."""
    looks = (RoverLook("red", RED_BGR, body_bgr=BLACK), RoverLook("green", GREEN_BGR, body_bgr=BLACK))
    effects = replace(STREAM, noise=Effects().noise, compression=Compression(75, "4:2:0"))
    renderer = Renderer(paper_camera(), Scene(looks), effects, seed=3)
    state = WorldState(
        0.0, (RoverState("red", 120.0, 210.0, 1.2, 0, 0, 0), RoverState("green", 205.0, 330.0, 2.6, 0, 0, 0))
    )
    return [renderer.render(state, k) for k in range(n)]


def _mean_error(estimates: list[tuple[str, float, float]], truth: dict[str, tuple[float, float]]) -> dict[str, float]:
    out = {}
    for rid, (tx, ty) in truth.items():
        own = np.array([(x - tx, y - ty) for r, x, y in estimates if r == rid])
        out[rid] = float(np.hypot(*own.mean(axis=0)))
    return out


@pytest.mark.slow
def test_the_pipeline_with_edge_offsets_takes_the_4_2_0_bias_out_of_the_reported_centres():
    frames = _still_rover_frames(60)
    rovers = (RoverConfig(id="red", color_bgr=(40, 40, 200)), RoverConfig(id="green", color_bgr=(60, 170, 40)))
    truth = {"red": (120.0, 210.0), "green": (205.0, 330.0)}
    biases = {}
    for on in (False, True):
        # the stream's camera does not sharpen, and the tracker is told so (SourceInfo.sharpened)
        config = TrackerConfig(rovers=rovers, edge_offsets=on, edge_offsets_every=3, camera_sharpens=False)
        fits = InlineFits(config.edge_offsets_every, delay_frames=2) if on else None
        tracker = build_tracker(config, CameraPlaneMapping(paper_camera()), None, fits=fits)
        got = []
        for k, image in enumerate(frames):
            result = tracker.process(Frame(image, k, k / 30.0, k / 30.0))
            if k >= 40:
                got += [(e.rover_id, e.measured_xy_cm[0], e.measured_xy_cm[1]) for e in result.estimates]
        assert {r for r, _, _ in got} == {"red", "green"}
        biases[on] = _mean_error(got, truth)
        if on:
            assert all(tracker.offsets.samples(i) >= MIN_SAMPLES for i in (0, 1))  # type: ignore[attr-defined]
    assert min(biases[False].values()) > 0.1  # the stream's bias, there to take out
    for rid in truth:  # each colour's centre moves towards the marker (by less than the fits' own error held back)
        assert biases[True][rid] < biases[False][rid] - TRUST_CM / 2
    assert sum(biases[True].values()) < 0.75 * sum(biases[False].values())


@pytest.mark.slow
def test_a_two_tone_marker_is_never_sent_to_the_edge_fits():
    frames = _still_rover_frames(20)
    rovers = (
        RoverConfig(id="red", color_bgr=(40, 40, 200), front_color_bgr=(200, 200, 200)),
        RoverConfig(id="green", color_bgr=(60, 170, 40)),
    )
    sent: list[int] = []
    fits = InlineFits(every_frames=1, delay_frames=0)
    submit = fits.submit
    fits.submit = lambda job: (sent.append(job.index), submit(job))  # type: ignore[method-assign]
    tracker = build_tracker(
        TrackerConfig(rovers=rovers, edge_offsets=True), CameraPlaneMapping(paper_camera()), fits=fits
    )
    for k, image in enumerate(frames):
        tracker.process(Frame(image, k, k / 30.0, k / 30.0))
    assert sent and set(sent) == {1}


@pytest.mark.slow
def test_the_appliances_tracker_fits_in_a_worker_process_and_close_stops_it():
    frames = _still_rover_frames(12)
    rovers = (RoverConfig(id="red", color_bgr=(40, 40, 200)), RoverConfig(id="green", color_bgr=(60, 170, 40)))
    tracker = build_tracker(TrackerConfig(rovers=rovers, edge_offsets=True), CameraPlaneMapping(paper_camera()))
    offsets = tracker.offsets  # type: ignore[attr-defined]
    fits = offsets.fits
    assert isinstance(fits, ProcessFits)  # the default: the frame loop is not held up by a fit
    for k, image in enumerate(frames):
        tracker.process(Frame(image, k, k / 30.0, k / 30.0))
    assert fits.wait(120.0)
    tracker.process(Frame(frames[-1], len(frames), len(frames) / 30.0, len(frames) / 30.0))
    assert sum(offsets.samples(i) for i in (0, 1)) >= 1 and fits.failed == 0
    tracker.close()  # type: ignore[attr-defined]
    assert fits._pool is None


def test_the_settings_reach_the_tracker():
    rovers = (RoverConfig(id="red", color_bgr=(40, 40, 200)),)
    mapping = CameraPlaneMapping(paper_camera())
    assert build_tracker(TrackerConfig(rovers=rovers), mapping).offsets is None  # type: ignore[attr-defined]
    tracker = build_tracker(TrackerConfig(rovers=rovers, edge_offsets=True, edge_offsets_every=7), mapping)
    assert tracker.offsets.fits.every_frames == 7  # type: ignore[attr-defined]
    tracker.close()  # type: ignore[attr-defined]


@contextmanager
def _worker_hit_by(grid: PlaneGrid, sig: int) -> Iterator[tuple[EdgeJob, ProcessFits]]:
    """A worker given a job at frame 0, then sent ``sig``; closed after."""
    job, _ = _job(grid, (150.0, 250.0, 1.0))
    fits = ProcessFits(every_frames=5)
    try:
        fits.submit(replace(job, frame=0))
        (pid,) = fits.worker_pids()
        os.kill(pid, sig)
        yield job, fits
    finally:
        fits.close()


@pytest.mark.slow
def test_a_worker_killed_mid_fit_costs_that_fit_and_a_new_one_serves_after_a_pause(grid):
    with _worker_hit_by(grid, signal.SIGKILL) as (job, fits):
        assert fits.wait(120.0)
        assert fits.collect(1) == [] and fits.failed == 1 and fits.worker_pids() == []
        assert not fits.ready(5) and not fits.ready(10)  # a pause of twice the cadence from when the loss was seen
        assert fits.ready(11)
        fits.submit(replace(job, frame=11))
        assert fits.wait(120.0)
        assert fits.collect(12) == [fit_offset(replace(job, frame=11))]


@pytest.mark.slow
def test_a_stalled_worker_is_killed_and_replaced(grid):
    with _worker_hit_by(grid, signal.SIGSTOP) as (job, fits):  # a worker that never finishes its fit
        assert not fits.ready(STALL_FRAMES - 1)
        assert not fits.ready(STALL_FRAMES)  # abandoned now, then a pause
        assert fits.failed == 1 and fits.worker_pids() == []
        assert fits.ready(STALL_FRAMES + 10)
        fits.submit(replace(job, frame=STALL_FRAMES + 10))
        assert fits.wait(120.0)
        assert fits.collect(STALL_FRAMES + 11) == [fit_offset(replace(job, frame=STALL_FRAMES + 10))]


@pytest.mark.slow
def test_a_sample_is_taken_against_the_filtered_centre_noted_for_its_frame(grid):
    job, _ = _job(grid, (150.0, 250.0, 1.0))
    offsets = CentreOffsets(InlineFits(every_frames=1, delay_frames=0))
    offsets.submit(replace(job, frame=4))
    smoothed = (job.centre_cm[0] + 0.03, job.centre_cm[1] - 0.02)  # the filter's centre that frame
    offsets.note_reference(0, 4, smoothed)
    assert offsets.collect(4) == 1
    (sample,) = offsets.maps[0].samples
    direct = fit_offset(job)
    assert direct is not None
    fitted = (job.centre_cm[0] + direct.offset_cm[0], job.centre_cm[1] + direct.offset_cm[1])
    assert sample.xy_cm == smoothed
    assert sample.offset_cm == pytest.approx((fitted[0] - smoothed[0], fitted[1] - smoothed[1]), abs=1e-12)


def _schedule(fits, jobs: list[EdgeJob], frames: int = 50, hurry_until: int = 5) -> list[tuple[int, bool, list]]:
    """Each frame: the samples collected, whether a job was taken (hurried for the first frames), the next of ``jobs``
    handed over when it was."""
    out = []
    k = 0
    for frame in range(frames):
        samples = fits.collect(frame)
        ready = fits.ready(frame, hurry=frame < hurry_until)
        if ready:
            fits.submit(replace(jobs[k % len(jobs)], frame=frame))
            k += 1
        out.append((frame, ready, samples))
    return out


@pytest.fixture(scope="module")
def three_jobs(grid) -> list[EdgeJob]:
    """Two windows that give a sample and one too small to (the fit's None)."""
    return [
        _job(grid, (150.0, 250.0, 1.0))[0],
        _job(grid, (200.0, 300.0, 0.3), half_px=13)[0],
        replace(_job(grid, (205.0, 330.0, 2.6))[0], index=1),
    ]


@pytest.mark.slow
def test_pooled_fits_give_the_loops_samples_at_the_same_frames(three_jobs):
    inline = _schedule(InlineFits(every_frames=10, delay_frames=15), three_jobs)
    fits = PooledFits(every_frames=10, delay_frames=15, workers=2)
    try:
        pooled = _schedule(fits, three_jobs)
        assert fits.worker_pids() and not fits.inline  # the pool did the fits
    finally:
        fits.close()
    assert pooled == inline
    taken = [frame for frame, ready, _ in inline if ready]
    assert taken == [0, 1, 2, 3, 4, 14, 24, 34, 44]
    released = [(frame, [s.frame for s in samples]) for frame, _, samples in inline if samples]
    # each job's sample 15 frames after it, none from the window too small to fit
    assert all(f == s + 15 for f, frames_ in released for s in frames_)
    assert {s.frame for _, _, samples in inline for s in samples} == {0, 2, 3, 14, 24}


def _fit_dying_in_a_worker(job: EdgeJob) -> EdgeSample | None:
    """``fit_offset``, except that in a worker process the job of frame 2 kills its worker."""
    if job.frame == 2 and multiprocessing.parent_process() is not None:
        os._exit(3)
    return fit_offset(job)


@pytest.mark.slow
def test_a_worker_that_dies_leaves_the_fits_to_the_loop_with_the_same_results(three_jobs, caplog):
    inline = _schedule(InlineFits(every_frames=10, delay_frames=15), three_jobs)
    fits = PooledFits(every_frames=10, delay_frames=15, workers=2, fit=_fit_dying_in_a_worker)
    try:
        with caplog.at_level(logging.WARNING, logger="edge.pooled_fits"):
            pooled = _schedule(fits, three_jobs)
        assert fits.inline and fits.worker_pids() == []  # the pool is stopped and not used again
    finally:
        fits.close()
    assert pooled == inline
    (warning,) = [r for r in caplog.records if r.name == "edge.pooled_fits"]  # logged once
    assert warning.levelno == logging.WARNING and "runs in the frame loop" in warning.getMessage()


def _fit_stuck_in_a_worker(job: EdgeJob) -> EdgeSample | None:
    """``fit_offset``, except that in a worker process it never finishes (a stuck worker)."""
    if multiprocessing.parent_process() is not None:
        threading.Event().wait()
    return fit_offset(job)


@pytest.mark.slow
def test_a_fit_not_done_after_the_guard_is_fitted_in_the_loop_and_the_pool_stopped(three_jobs, caplog):
    job = three_jobs[0]
    fits = PooledFits(every_frames=10, delay_frames=0, workers=1, fit=_fit_stuck_in_a_worker, guard_s=1.0)
    try:
        fits.submit(replace(job, frame=0))
        with caplog.at_level(logging.WARNING, logger="edge.pooled_fits"):
            assert fits.collect(0) == [fit_offset(job)]
        assert fits.inline and fits.worker_pids() == []
        assert "not done after 1 s" in caplog.text
        fits.submit(replace(job, frame=10))  # later jobs: in the loop
        assert fits.collect(10) == [fit_offset(replace(job, frame=10))]
    finally:
        fits.close()


def _fit_raising_in_a_worker(job: EdgeJob) -> EdgeSample | None:
    """``fit_offset``, except that in a worker process the job of frame 2 raises."""
    if job.frame == 2 and multiprocessing.parent_process() is not None:
        raise ValueError("a fit that fails in the worker")
    return fit_offset(job)


@pytest.mark.slow
def test_a_fit_that_raises_in_a_worker_is_fitted_in_the_loop_and_the_pool_serves_on(three_jobs):
    inline = _schedule(InlineFits(every_frames=10, delay_frames=15), three_jobs)
    fits = PooledFits(every_frames=10, delay_frames=15, workers=2, fit=_fit_raising_in_a_worker)
    try:
        pooled = _schedule(fits, three_jobs)
        assert not fits.inline and fits.worker_pids()  # the pool still serves
    finally:
        fits.close()
    assert pooled == inline


def test_a_pool_that_cannot_start_leaves_the_fits_to_the_loop(monkeypatch, caplog):
    def no_processes(*args, **kwargs):
        raise OSError(11, "Resource temporarily unavailable")

    monkeypatch.setattr("edge.pooled_fits.ProcessPoolExecutor", no_processes)
    job = EdgeJob(0, 0, np.zeros((4, 4, 3), np.uint8), np.zeros((2, 4, 4)), (0.0, 0.0), 0.0, SIZE_CM)
    fits = PooledFits(every_frames=10, delay_frames=3)
    with caplog.at_level(logging.WARNING, logger="edge.pooled_fits"):
        fits.submit(job)
        fits.submit(replace(job, frame=1))
    assert fits.inline and "could not take a job" in caplog.text and len(caplog.records) == 1
    assert fits.collect(4) == []  # fitted here: a window of no marker pixels gives no sample
    assert not fits._pending


_STARTS_A_WORKER = """
import json, sys
import numpy as np
from edge.centre_offsets import EdgeJob
from edge.fit_worker import ProcessFits
from edge.pooled_fits import PooledFits
job = EdgeJob(0, 0, np.zeros((4, 4, 3), np.uint8), np.zeros((2, 4, 4)), (0.0, 0.0), 0.0, (21.5, 16.8))
if sys.argv[1] == "pooled":
    fits = PooledFits(every_frames=10, delay_frames=0, workers=1)
    fits.submit(job)
    fits.collect(0)  # waits for the worker's fit
else:
    fits = ProcessFits()
    fits.submit(job)
    fits.wait(60.0)
print(json.dumps(fits.worker_pids()), flush=True)
sys.stdin.read()  # until killed
"""


def _ends(pid: int, timeout_s: float) -> bool:
    """Wait (on the process's pidfd) until ``pid`` has ended; False on timeout."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], timeout_s)[0])
    finally:
        os.close(fd)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["pooled", "process"])
def test_the_fits_workers_end_when_the_process_that_started_them_is_killed(kind):
    """``kill -9`` of ``edge-ips track`` or of the appliance runs no ``finally``: the idle workers would wait for jobs
    for ever, reparented. They watch their parent and end with it."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _STARTS_A_WORKER, kind],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    try:
        assert proc.stdout is not None
        pids = json.loads(proc.stdout.readline())
        assert len(pids) == 1 and _ends(pids[0], 0.0) is False  # a worker, alive
    finally:
        proc.kill()
        proc.wait()
    assert _ends(pids[0], 60.0)


@pytest.mark.slow
def test_closing_the_pooled_fits_ends_their_workers(three_jobs):
    fits = PooledFits(every_frames=10, delay_frames=15, workers=2)
    _schedule(fits, three_jobs[:1])
    pids = fits.worker_pids()
    assert pids
    fits.close()
    assert all(_ends(pid, 60.0) for pid in pids)
