"""``edge_offsets = "auto"`` (the default): the edge fits follow the source. A camera's, a video file's or a stream's
frames have been through a colour path that spreads the chroma (a webcam's MJPG at 4:2:0, YUYV at 4:2:2, a codec),
the simulator's uncompressed frames have not; ``true`` and ``false`` say what they mean whatever the source."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from edge.appliance import TrackerInputs, default_tracker_factory
from edge.calibration.exact import exact_calibration
from edge.calibration.files import save_calibration
from edge.camera import paper_camera
from edge.config import EdgeConfig
from edge.errors import ConfigError
from edge.fit_worker import ProcessFits
from edge.offline import open_track_job
from edge.pooled_fits import PooledFits
from edge.sim.effects import Effects, SignalProcessing
from edge.sim.source import SimSource
from edge.sources import MemorySource, SourceInfo, VideoFileSource
from edge.tracker_config import RoverConfig, TrackerConfig, edge_offsets_on, load_tracker_config
from edge.trackers.base import CameraPlaneMapping
from edge.trackers.factory import build_tracker
from tests.support.runtime import write_clip

ROVERS = (RoverConfig(id="red", color_bgr=(40, 40, 200)),)


@pytest.mark.parametrize(
    ("setting", "spread", "on"),
    [("auto", True, True), ("auto", False, False), (True, False, True), (False, True, False)],
)
def test_auto_follows_the_source_and_true_or_false_do_not(setting: bool | str, spread: bool, on: bool) -> None:
    assert edge_offsets_on(setting, spread) is on  # type: ignore[arg-type]
    config = TrackerConfig(rovers=ROVERS, edge_offsets=setting)  # type: ignore[arg-type]
    assert config.for_source(spread).edge_offsets is on


def test_the_default_is_auto_and_the_pipeline_alone_takes_it_as_off() -> None:
    config = TrackerConfig(rovers=ROVERS)
    assert config.edge_offsets == "auto"
    # built without a source (a library caller), nothing says the frames were spread: no worker is started
    assert build_tracker(config, CameraPlaneMapping(paper_camera())).offsets is None  # type: ignore[attr-defined]


@pytest.mark.parametrize(("text", "value"), [('"auto"', "auto"), ("true", True), ("false", False)])
def test_the_setting_is_read_from_toml(tmp_path: Path, text: str, value: bool | str) -> None:
    path = tmp_path / "tracker.toml"
    path.write_text(f'edge_offsets = {text}\n[[rovers]]\nid = "red"\ncolor_bgr = [40, 40, 200]\n')
    assert load_tracker_config(path).edge_offsets == value


@pytest.mark.parametrize("text", ['"sometimes"', "2", '"maybe"'])
def test_another_value_is_one_clear_line(tmp_path: Path, text: str) -> None:
    path = tmp_path / "tracker.toml"
    path.write_text(f'edge_offsets = {text}\n[[rovers]]\nid = "red"\ncolor_bgr = [40, 40, 200]\n')
    with pytest.raises(ConfigError, match="edge_offsets") as caught:
        load_tracker_config(path)
    assert "\n" not in str(caught.value).strip()


def test_sources_say_whether_their_colour_was_spread(tmp_path: Path) -> None:
    video = VideoFileSource(write_clip(tmp_path / "clip.avi", frames=2), realtime=False)
    assert video.open().chroma_spread  # a codec's frames
    video.close()
    image = np.zeros((8, 8, 3), np.uint8)
    assert MemorySource([image]).open().chroma_spread  # frames handed in: taken as a camera's
    assert not MemorySource([image], chroma_spread=False).open().chroma_spread
    # the simulator: uncompressed scenes are not spread, the one it sends through MJPG compression is
    assert not SimSource("lab", realtime=False).open().chroma_spread
    assert SimSource("lens", realtime=False).open().chroma_spread


@pytest.mark.parametrize(
    ("spread", "setting", "on"), [(True, "auto", True), (False, "auto", False), (False, True, True)]
)
def test_the_appliances_tracker_decides_by_the_opened_source(spread: bool, setting: bool | str, on: bool) -> None:
    config = EdgeConfig.model_validate(
        {"tracker": {"edge_offsets": setting}, "rovers": [{"id": "red", "color_bgr": [40, 40, 200]}]}
    )
    image = np.zeros((720, 1280, 3), np.uint8)
    source = MemorySource([image], chroma_spread=spread)
    inputs = TrackerInputs(config, source, source.open(), CameraPlaneMapping(paper_camera()))
    tracker = default_tracker_factory(inputs)
    try:
        offsets = tracker.offsets  # type: ignore[attr-defined]
        assert (offsets is not None) is on
        if on:
            assert isinstance(offsets.fits, ProcessFits)  # in the appliance: a worker process, started on a first fit
    finally:
        tracker.close()


def test_a_video_is_tracked_with_the_fits_pooled_on_the_loops_schedule_unless_turned_off(tmp_path: Path) -> None:
    clip = write_clip(tmp_path / "clip.avi", frames=2, width=1280, height=720)
    calibration = tmp_path / "calibration.json"
    save_calibration(exact_calibration(paper_camera()), calibration)
    job = open_track_job(clip, calibration, TrackerConfig(rovers=ROVERS))
    try:
        assert isinstance(job.tracker.offsets.fits, PooledFits)  # type: ignore[attr-defined]
    finally:
        job.frames.close()
    job = open_track_job(clip, calibration, TrackerConfig(rovers=ROVERS, edge_offsets=False))
    try:
        assert job.tracker.offsets is None  # type: ignore[attr-defined]
    finally:
        job.frames.close()


def test_source_info_defaults_to_a_spread_colour_path() -> None:
    # a source written elsewhere that says nothing is taken as a camera's: the fits are on for it, its luma may be
    # sharpened
    info = SourceInfo(1280, 720, 30.0, "somewhere")
    assert info.chroma_spread and info.sharpened


@pytest.mark.parametrize("sharpened", [True, False])
def test_the_appliances_edge_fits_weigh_the_luma_unless_the_camera_is_known_not_to_sharpen(sharpened: bool) -> None:
    """The source says whether its camera may sharpen (``SourceInfo.sharpened``); the tracker's edge fits weigh the
    luma by their residuals where it may (``edge.edges_encoded``): the tracker's offsets, which write every job
    sent to the fits, are told."""
    config = EdgeConfig.model_validate({"rovers": [{"id": "red", "color_bgr": [40, 40, 200]}]})
    source = MemorySource([np.zeros((720, 1280, 3), np.uint8)])
    info = SourceInfo(1280, 720, 30.0, "a camera", sharpened=sharpened)
    tracker = default_tracker_factory(TrackerInputs(config, source, info, CameraPlaneMapping(paper_camera())))
    try:
        assert tracker.config.camera_sharpens is sharpened  # type: ignore[attr-defined]
        assert tracker.offsets.sharpened is sharpened  # type: ignore[attr-defined]
    finally:
        tracker.close()  # type: ignore[attr-defined]


def test_the_simulator_says_whether_its_camera_sharpens() -> None:
    assert not SimSource("lab", realtime=False).open().sharpened  # the nominal camera: no image processor
    assert not Effects().sharpens
    assert not Effects(processing=SignalProcessing(sharpen=0.0)).sharpens
    assert Effects(processing=SignalProcessing(sharpen=0.4)).sharpens


@pytest.mark.parametrize(("text", "value"), [("true", True), ("OFF", False), ("auto", "auto")])
def test_an_environment_override_is_read(text: str, value: bool | str) -> None:
    from edge.config_load import load_config

    loaded = load_config(None, {"EDGE_IPS_TRACKER__EDGE_OFFSETS": text})
    assert loaded.config.tracker.edge_offsets == value


def test_the_appliance_says_the_fits_are_on(caplog: pytest.LogCaptureFixture) -> None:
    config = EdgeConfig.model_validate({"rovers": [{"id": "red", "color_bgr": [40, 40, 200]}]})
    source = MemorySource([np.zeros((720, 1280, 3), np.uint8)])
    with caplog.at_level("INFO", logger="edge.fit_worker"):
        tracker = default_tracker_factory(
            TrackerInputs(config, source, source.open(), CameraPlaneMapping(paper_camera()))
        )
    tracker.close()  # type: ignore[attr-defined]
    assert any("edge offsets on" in r.getMessage() for r in caplog.records)
