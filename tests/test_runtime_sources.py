"""Frame sources, the newest-frame slot and the capture thread that reopens a vanished source with backoff."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from edge.capture import CaptureThread, FrameSlot
from edge.errors import SourceError
from edge.source_spec import make_source, parse_source
from edge.sources import (
    CameraSource,
    Frame,
    MemorySource,
    SourceInfo,
    StreamSource,
    VideoFileSource,
)
from tests.support.runtime import MjpegServer, scene, write_clip


def _frame(index: int) -> Frame:
    return Frame(np.zeros((2, 2, 3), np.uint8), index, time.time(), time.monotonic())


@pytest.mark.parametrize(
    ("text", "kind", "target"),
    [
        ("sim", "sim", ""),
        ("sim:crossing", "sim", "crossing"),
        ("0", "camera", "/dev/video0"),
        ("2", "camera", "/dev/video2"),
        ("/dev/video1", "camera", "/dev/video1"),
        ("/dev/v4l/by-id/usb-046d_C920-video-index0", "camera", "/dev/v4l/by-id/usb-046d_C920-video-index0"),
        ("rtsp://cam.local/stream1", "stream", "rtsp://cam.local/stream1"),
        ("http://10.0.0.5:8080/video.mjpg", "stream", "http://10.0.0.5:8080/video.mjpg"),
        ("clips/run1.mp4", "file", "clips/run1.mp4"),
        ("simulation.avi", "file", "simulation.avi"),
    ],
)
def test_source_spec_is_parsed(text: str, kind: str, target: str) -> None:
    spec = parse_source(text)
    assert (spec.kind, spec.target) == (kind, target)


def test_slot_gives_the_newest_frame_and_counts_the_overwritten() -> None:
    slot = FrameSlot()
    for i in range(3):
        slot.put(_frame(i))
    got = slot.take(timeout_s=0)
    assert got is not None and got.index == 2
    assert slot.overwritten == 2
    assert slot.take(timeout_s=0) is None  # nothing new since
    assert slot.peek() is got  # a viewer still sees the newest frame


def test_slot_close_wakes_a_waiting_consumer() -> None:
    slot = FrameSlot()
    woke = threading.Event()

    def consumer() -> None:
        slot.take(timeout_s=None)
        woke.set()

    threading.Thread(target=consumer, daemon=True).start()
    slot.close()
    assert woke.wait(5)


class FlakySource:
    """A scripted source: ``opens`` says which open attempts fail; reads fail after ``frames_per_open`` frames."""

    def __init__(self, open_results: list[bool], frames_per_open: int) -> None:
        self.open_results = list(open_results)
        self.frames_per_open = frames_per_open
        self.open_times: list[float] = []
        self.closed = 0
        self._left = 0
        self._index = 0

    def open(self) -> SourceInfo:
        self.open_times.append(time.monotonic())
        ok = self.open_results.pop(0) if self.open_results else True
        if not ok:
            raise SourceError("camera unplugged")
        self._left = self.frames_per_open
        self._index = 0  # a reopened camera counts from 0 again
        return SourceInfo(2, 2, 30.0, "flaky")

    def read(self) -> Frame | None:
        if self._left == 0:
            raise SourceError("read failed")
        self._left -= 1
        time.sleep(0.001)
        frame = _frame(self._index)
        self._index += 1
        return frame

    def close(self) -> None:
        self.closed += 1


@pytest.mark.slow
def test_capture_thread_reopens_with_backoff_and_keeps_indices_increasing() -> None:
    # first open done by the runtime; then the source fails, 3 reopen attempts fail, the 4th works
    source = FlakySource([True, False, False, False, True], frames_per_open=5)
    info = source.open()
    slot, stop = FrameSlot(), threading.Event()
    capture = CaptureThread(source, slot, stop, info=info, reopen_min_s=0.05, reopen_max_s=1.0)
    seen: list[int] = []
    capture.start()
    deadline = time.monotonic() + 30
    while len(seen) < 8 and time.monotonic() < deadline:
        frame = slot.take(timeout_s=0.5)
        if frame is not None:
            seen.append(frame.index)
    stop.set()
    capture.join(5)
    assert len(seen) >= 8
    assert seen == sorted(set(seen)), "frame indices must keep increasing across a reopen"
    assert capture.failures >= 1 and capture.reopens >= 1
    gaps = np.diff(source.open_times[1:5])  # waits before attempts 2, 3, 4 after the first failed reopen
    assert gaps[0] >= 0.1 * 0.95 and gaps[1] >= 0.2 * 0.95, f"backoff must double: {gaps}"
    assert capture.state == "stopped"


def test_capture_thread_ends_with_a_finite_source() -> None:
    source = MemorySource([scene(i) for i in range(4)])
    slot, stop = FrameSlot(), threading.Event()
    capture = CaptureThread(source, slot, stop, info=source.open())
    capture.start()
    capture.join(10)
    assert capture.ended and capture.frames == 4 and slot.closed


def test_video_file_plays_to_the_end(tmp_path: Path) -> None:
    clip = write_clip(tmp_path / "clip.avi", frames=12)
    source = VideoFileSource(clip, realtime=False)
    info = source.open()
    assert (info.width_px, info.height_px, info.fps) == (320, 240, 30.0)
    frames = []
    while (frame := source.read()) is not None:
        frames.append(frame)
    source.close()
    assert [f.index for f in frames] == list(range(12))
    assert frames[0].image.shape == (240, 320, 3)


@pytest.mark.slow
def test_video_file_loops_and_paces_in_real_time(tmp_path: Path) -> None:
    clip = write_clip(tmp_path / "clip.avi", frames=10, fps=50.0)
    source = VideoFileSource(clip, loop=True, realtime=True)
    source.open()
    t0 = time.monotonic()
    frames = [source.read() for _ in range(25)]
    elapsed = time.monotonic() - t0
    source.close()
    assert all(f is not None for f in frames)
    assert [f.index for f in frames if f is not None] == list(range(25))
    assert elapsed >= 24 / 50.0 * 0.95  # paced at the file's 50 fps, not as fast as it decodes


def test_missing_camera_suggests_the_simulator() -> None:
    with pytest.raises(SourceError, match=r"no camera at /dev/video97 .*--source sim"):
        CameraSource("/dev/video97").open()


@pytest.mark.parametrize(
    ("text", "message"),
    [("missing.avi", r"missing.avi: video file not found"), ("sim", r"simulated camera .* not available")],
)
def test_unopenable_sources_say_why(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(SourceError, match=message):
        make_source(str(tmp_path / text) if text != "sim" else text).open()


@pytest.mark.parametrize("realtime", [True, False])
def test_the_simulator_is_built_paced_as_the_caller_asks(realtime: bool) -> None:
    """A reader of consecutive frames (``calibrate line-time``) asks for them unpaced; the factory must hear it."""
    asked: list[tuple[str, bool]] = []

    def factory(scenario: str, *, realtime: bool) -> MemorySource:
        asked.append((scenario, realtime))
        return MemorySource([np.zeros((2, 2, 3), np.uint8)], realtime=realtime)

    source = make_source("sim:sun", realtime=realtime, sim_factory=factory)
    assert asked == [("sun", realtime)]
    assert isinstance(source, MemorySource) and source.realtime is realtime


def test_not_a_video_file_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "notes.avi"
    bad.write_text("not a video")
    with pytest.raises(SourceError, match="not a video file"):
        VideoFileSource(bad).open()


@pytest.mark.slow
def test_stream_reads_then_fails_when_stalled_and_cannot_reopen_a_dead_server() -> None:
    server = MjpegServer(fps=30).start()
    source = StreamSource(server.url, open_timeout_s=2.0, read_timeout_s=0.5)
    try:
        info = source.open()
        assert (info.width_px, info.height_px) == (320, 240)
        assert source.read().image.shape == (240, 320, 3)  # type: ignore[union-attr]
        server.stalled.set()
        with pytest.raises(SourceError, match="stream stalled"):
            for _ in range(200):  # frames already buffered come first
                source.read()
        source.close()
        server.stop()
        with pytest.raises(SourceError, match="cannot be opened"):
            source.open()
    finally:
        server.stop()


def test_stream_credentials_never_appear_in_messages() -> None:
    source = StreamSource("rtsp://admin:hunter2@127.0.0.1:1/x", open_timeout_s=0.5)
    with pytest.raises(SourceError) as err:
        source.open()
    assert "hunter2" not in str(err.value)
