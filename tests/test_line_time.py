"""The rolling shutter's line time from the lamps' flicker bands (``edge.line_time``, ``edge-ips calibrate
line-time``): the simulator's rolling flicker exposes row r at ``t + r * line_time``, as a rolling shutter does."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from edge.camera import paper_camera
from edge.cli import main
from edge.line_time import NoFlicker, line_time_from_flicker
from edge.sim.effects import Compression, Effects, Exposure, Flicker
from edge.sim.render import Renderer
from edge.sim.scene import Scene, fleet_looks
from edge.sim.world import RoverState, WorldState


def _frames(
    line_time_us: float, mains_hz: float, fps: float, exposure_s: float = 1 / 2000, count: int = 24
) -> list[np.ndarray]:
    """An MJPG camera (4:2:0 q70, noise, auto-exposure) over the lab floor with a rover driving through, under lamps
    rippling by 30 %."""
    effects = Effects(
        exposure=Exposure(exposure_s=exposure_s),
        flicker=Flicker(mains_hz=mains_hz, modulation=0.3, line_time_s=line_time_us * 1e-6),
        compression=Compression(70, "4:2:0"),
    )
    renderer = Renderer(paper_camera(), Scene(fleet_looks(1)), effects, fps=fps)
    out = []
    for i in range(count):
        rover = RoverState(renderer.scene.rovers[0].rover_id, 100.0 + 3.0 * i, 250.0, 0.0, 90.0, 0.0, 90.0)
        out.append(renderer.render(WorldState(i / fps, (rover,)), i))
    return out


@pytest.mark.parametrize(
    ("line_time_us", "mains_hz", "fps"),
    [(44.4, 50.0, 30.0), (30.0, 50.0, 30.0), (40.0, 60.0, 25.0), (20.0, 60.0, 30.5)],
)
def test_the_line_time_is_read_off_the_bands_of_a_compressed_noisy_stream(
    line_time_us: float, mains_hz: float, fps: float
) -> None:
    result = line_time_from_flicker(_frames(line_time_us, mains_hz, fps), mains_hz, fps)
    assert result.line_time_us == pytest.approx(line_time_us, rel=0.005)
    assert result.period_rows == pytest.approx(1e6 / (2 * mains_hz * line_time_us), rel=0.005)
    assert result.contrast > 0.1 and result.share > 0.5


def test_an_exposure_of_whole_ripple_periods_shows_no_bands_and_says_what_to_change() -> None:
    with pytest.raises(NoFlicker, match="short manual exposure"):
        line_time_from_flicker(_frames(44.4, 50.0, 30.0, exposure_s=1 / 100), 50.0, 30.0)


def test_bands_that_stand_still_from_frame_to_frame_are_not_taken_for_the_scene() -> None:
    """At 30 fps under 60 Hz mains every frame has the same bands: the median over frames would hold them. The
    measurement says which frame rate to use instead of returning a wrong line time."""
    with pytest.raises(NoFlicker, match="25 fps"):
        line_time_from_flicker(_frames(44.4, 60.0, 30.0, count=8), 60.0, 30.0)


def test_a_camera_reading_out_too_fast_for_its_bands_to_be_measured_is_refused_not_misread() -> None:
    """At 10 us a row the bands are 1000 rows apart, more than a 720-row frame: a fit to less than a band landed on
    the searched range's end (9.26 us for any line time under 12) and was reported."""
    with pytest.raises(NoFlicker, match="reads out fast"):
        line_time_from_flicker(_frames(10.0, 50.0, 30.0), 50.0, 30.0)


def test_too_few_frames_are_refused() -> None:
    with pytest.raises(NoFlicker, match="at least 8"):
        line_time_from_flicker(_frames(44.4, 50.0, 30.0, count=3), 50.0, 30.0)


def test_the_simulator_for_a_reader_of_consecutive_frames_is_not_paced_whatever_the_configuration() -> None:
    """Paced in real time, a reader slower than the frame rate (a loaded machine) gets the newest frame and skips some:
    the bands no longer roll by one frame's time (the likely cause of ``calibrate line-time`` taking the sun scene,
    which has no flicker, for banded in one CI run on 2026-12-04)."""
    from edge.appliance import default_sim_factory
    from edge.config import EdgeConfig
    from edge.source_spec import camera_source

    config = EdgeConfig.model_validate({"camera": {"source": "sim:sun"}})
    assert config.camera.realtime  # the default: the simulator delivers at its frame rate
    paced = camera_source(config.camera, default_sim_factory(config))
    unpaced = camera_source(config.camera, default_sim_factory(config), realtime=False)
    assert paced.realtime and not unpaced.realtime  # type: ignore[attr-defined]
    off = EdgeConfig.model_validate({"camera": {"source": "sim:sun", "realtime": False}})
    assert not camera_source(off.camera, default_sim_factory(off)).realtime  # type: ignore[attr-defined]


@pytest.mark.slow
def test_calibrate_line_time_reads_the_simulated_lab_and_refuses_a_scene_without_flicker() -> None:
    """The lab scene's lamps ripple by 20 % (bands of 3.3 % in linear light at its 1/60 s automatic exposure, 1.5 % in
    the 8-bit values), rovers drive through it."""
    runner = CliRunner()
    ok = runner.invoke(main, ["calibrate", "line-time", "--source", "sim:lab", "--mains", "50", "--json"])
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.output)["line_time_us"] == pytest.approx(1e6 / (30 * 750), rel=0.005)
    none = runner.invoke(main, ["calibrate", "line-time", "--source", "sim:sun", "--mains", "50"])
    assert none.exit_code == 2
    assert "no flicker bands" in none.output and "Traceback" not in none.output


@pytest.mark.parametrize(
    ("available", "count", "settle", "expected"),
    [(15, 3, 2, [2, 3, 4]), (5, 10, 2, [2, 3, 4]), (2, 3, 5, [1]), (12, 1, 9, [9])],
)
def test_frames_are_grabbed_after_the_settling_ones(
    available: int, count: int, settle: int, expected: list[int]
) -> None:
    """The frames after the camera's exposure settled; fewer when the source ends; the last one when it ends while
    settling (a single frame for `rovers enroll`, 60 for `calibrate line-time`)."""
    from edge.sources import MemorySource, grab_frames

    images = [np.full((4, 4, 3), i, np.uint8) for i in range(available)]
    got = grab_frames(MemorySource(images), count, settle)
    assert [int(g[0, 0, 0]) for g in got] == expected
