"""SimSource: the simulator as a camera for the runtime, with ground truth and deterministic frames."""

from __future__ import annotations

import numpy as np
import pytest

from edge.errors import SimulationError, SourceError
from edge.sim.source import SimSource
from edge.sources import FrameSource


class FakeClock:
    """A monotonic clock that only moves when something sleeps (or the test advances it)."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


def _source(clock: FakeClock | None = None, **kwargs) -> SimSource:
    clock = clock or FakeClock()
    return SimSource(clock=clock, wall_clock=lambda: 1.7e9 + clock.now, sleep=clock.sleep, **kwargs)


def test_sim_source_is_a_frame_source_that_reports_what_it_delivers():
    source = _source(scenario="lab", seed=0, realtime=False, frames=3)
    assert isinstance(source, FrameSource)
    info = source.open()
    assert (info.width_px, info.height_px, info.fps) == (1280, 720, 30.0)
    assert "sim:lab" in info.description
    frames = [source.read() for _ in range(4)]
    assert [f.index for f in frames[:3] if f is not None] == [0, 1, 2]
    assert frames[3] is None
    first = frames[0]
    assert first is not None
    assert first.image.shape == (720, 1280, 3) and first.image.dtype == np.uint8
    source.close()


@pytest.mark.slow
def test_truth_is_the_world_at_the_frames_time():
    source = _source(scenario="lab", seed=1, realtime=False, frames=40)
    source.open()
    for _ in range(40):
        source.read()
    truth = source.truth(37)
    state = source.setup.world().state_at(37 / 30)
    assert truth.t_s == pytest.approx(37 / 30)
    for r, s in zip(truth.rovers, state.rovers, strict=True):
        assert (r.rover_id, r.x_cm, r.y_cm, r.theta_rad, r.vx_cm_s, r.vy_cm_s) == (
            s.rover_id,
            s.x_cm,
            s.y_cm,
            s.theta_rad,
            s.vx_cm_s,
            s.vy_cm_s,
        )
        assert r.visible == pytest.approx(1.0, abs=1e-6)


@pytest.mark.slow
def test_same_seed_gives_the_same_frames_and_truth():
    a = _source(scenario="drift", seed=5, realtime=False, frames=6)
    b = _source(scenario="drift", seed=5, realtime=False, frames=6)
    a.open()
    b.open()
    for _ in range(6):
        fa, fb = a.read(), b.read()
        assert fa is not None and fb is not None
        np.testing.assert_array_equal(fa.image, fb.image)
        assert a.truth(fa.index) == b.truth(fb.index)


def test_realtime_paces_frames_at_30_fps():
    clock = FakeClock()
    source = _source(clock, scenario="lab", seed=0, realtime=True, frames=10)
    source.open()
    start = clock.now
    stamps = []
    for _ in range(10):
        frame = source.read()
        assert frame is not None
        stamps.append(frame.t_mono_s - start)
    np.testing.assert_allclose(stamps, np.arange(10) / 30.0, atol=1e-9)


def test_a_late_reader_gets_the_newest_frame_not_a_backlog():
    clock = FakeClock()
    source = _source(clock, scenario="lab", seed=0, realtime=True)
    source.open()
    assert source.read().index == 0
    clock.now += 0.5  # the reader was busy for half a second
    frame = source.read()
    assert frame.index == 15
    with pytest.raises(SimulationError, match="no ground truth for frame 7"):
        source.truth(7)


def test_endless_source_replays_the_scenario():
    source = _source(scenario="lab", seed=0, realtime=False)
    source.open()
    period = source.setup.frames
    source.render(3)
    source.render(period + 3)
    a, b = source.truth(3), source.truth(period + 3)
    assert [(r.x_cm, r.y_cm) for r in a.rovers] == [(r.x_cm, r.y_cm) for r in b.rovers]


def test_rover_configs_come_from_the_scene():
    source = _source(scenario="crowd", seed=0, realtime=False, rovers=5)
    ids = [c.id for c in source.rover_configs()]
    assert ids == [look.rover_id for look in source.setup.scene.rovers]
    assert len(set(c.color_bgr for c in source.rover_configs())) == 5


def test_reading_before_opening_is_an_error():
    with pytest.raises(SourceError, match="before open"):
        _source(realtime=False).read()


def test_truth_history_is_bounded():
    source = _source(scenario="lab", realtime=False, history=3)
    source.open()
    for _ in range(5):
        source.read()
    assert source.truth(4).frame_index == 4
    with pytest.raises(SimulationError, match="frame 1"):
        source.truth(1)
