"""A camera that comes back at another resolution: the tracker never gets a frame of another size than it was
calibrated for, the edge says so once and waits (status degraded, the reason in /healthz), never a crash and never
a restart loop; when the camera delivers the calibrated size again, tracking resumes by itself."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Sequence

import numpy as np
import pytest

from edge.appliance import TrackerInputs
from edge.calibration.exact import exact_calibration
from edge.camera import PinholeCamera
from edge.capture import CaptureThread, FrameSlot
from edge.errors import SourceError
from edge.sources import SourceInfo
from edge.tracker_config import TrackerConfig
from edge.trackers.factory import build_tracker
from edge.tracking import Frame, FrameResult
from tests.support.appliance import edge_config, running
from tests.support.mosquitto import Mosquitto
from tests.support.runtime import CentroidTracker, MjpegServer, MqttRecorder, poses, statuses


class ResizingSource:
    """A camera that is unplugged after ``frames_per_open`` frames and comes back at the next size of ``sizes``."""

    def __init__(self, sizes: Sequence[tuple[int, int]], frames_per_open: int = 3) -> None:
        self.sizes = list(sizes)
        self.frames_per_open = frames_per_open
        self.opens = 0
        self.opened = threading.Condition()
        self._size = self.sizes[0]
        self._left = 0
        self._index = 0

    def open(self) -> SourceInfo:
        with self.opened:
            self._size = self.sizes[min(self.opens, len(self.sizes) - 1)]
            self.opens += 1
            self.opened.notify_all()
        self._left = self.frames_per_open
        return SourceInfo(self._size[0], self._size[1], 30.0, f"camera {self._size[0]}x{self._size[1]}")

    def read(self) -> Frame | None:
        if self._left == 0:
            raise SourceError("camera unplugged")
        self._left -= 1
        self._index += 1
        w, h = self._size
        return Frame(np.zeros((h, w, 3), np.uint8), self._index, time.time(), time.monotonic())

    def close(self) -> None:
        pass

    def wait_opens(self, n: int, timeout_s: float = 30.0) -> bool:
        with self.opened:
            return self.opened.wait_for(lambda: self.opens >= n, timeout_s)


def test_a_camera_back_at_another_size_is_held_back_said_once_and_waited_for(caplog: pytest.LogCaptureFixture) -> None:
    # first open at 320x240 (what the calibration is for), then four reopens at 640x480, then 320x240 again
    source = ResizingSource([(320, 240)] + [(640, 480)] * 4 + [(320, 240)], frames_per_open=3)
    slot, stop = FrameSlot(), threading.Event()
    capture = CaptureThread(source, slot, stop, info=source.open(), reopen_min_s=0.01, reopen_max_s=0.02)
    sizes: list[tuple[int, int]] = []
    with caplog.at_level(logging.DEBUG, logger="edge.sources"):
        capture.start()
        assert source.wait_opens(3)
        assert capture.state == "missing" and "640x480" in capture.problem and "320x240" in capture.problem
        while len(sizes) < 5:  # 3 frames before the unplug, then frames after the camera is right again
            frame = slot.take(timeout_s=30)
            assert frame is not None
            sizes.append((frame.image.shape[1], frame.image.shape[0]))
        stop.set()
        capture.join(10)
    assert set(sizes) == {(320, 240)}, "no frame of another size reaches the tracker"
    assert source.opens >= 6 and capture.reopens >= 1 and capture.problem == ""
    said = [r for r in caplog.records if "640x480" in r.getMessage() and r.levelno >= logging.WARNING]
    assert len(said) == 1, [r.getMessage() for r in said]
    assert "calibrate at 640x480" in said[0].getMessage()


class StreamChangingSize(ResizingSource):
    """A stream that switches to another resolution mid-stream, without a reconnect."""

    def read(self) -> Frame | None:
        frame = super().read()
        if self.opens == 1 and self._index > 2 and frame is not None:
            return Frame(np.zeros((480, 640, 3), np.uint8), frame.index, frame.t_capture_s, frame.t_mono_s)
        return frame


def test_a_stream_that_changes_size_mid_stream_is_reopened_not_passed_on() -> None:
    source = StreamChangingSize([(320, 240)], frames_per_open=10)
    slot, stop = FrameSlot(), threading.Event()
    capture = CaptureThread(source, slot, stop, info=source.open(), reopen_min_s=0.01, reopen_max_s=0.02)
    capture.start()
    sizes = []
    while len(sizes) < 6:
        frame = slot.take(timeout_s=30)
        assert frame is not None
        sizes.append(frame.image.shape[:2])
    stop.set()
    capture.join(10)
    assert set(sizes) == {(240, 320)} and capture.failures >= 1 and capture.reopens >= 1


class BothTrackers:
    """The real pipeline (which refuses a frame of another size, killing the runtime) beside the fake tracker that
    finds :func:`scene`'s discs: the poses come from the fake one, the size check from the real one."""

    def __init__(self, inputs: TrackerInputs) -> None:
        self.real = build_tracker(TrackerConfig(), inputs.calibration)
        self.fake = CentroidTracker()
        self.sizes: set[tuple[int, int]] = set()

    def process(self, frame: Frame) -> FrameResult:
        self.sizes.add((frame.image.shape[1], frame.image.shape[0]))
        self.real.process(frame)
        return self.fake.process(frame)

    def reset(self) -> None:
        self.real.reset()

    def close(self) -> None:
        self.real.close()


@pytest.mark.slow
def test_the_appliance_waits_for_a_stream_back_at_another_size_and_resumes(
    mosquitto: Mosquitto, caplog: pytest.LogCaptureFixture
) -> None:
    camera = PinholeCamera.look_at((160.0, -150.0, 250.0), (160.0, 200.0, 0.0), width_px=320, height_px=240)
    server = MjpegServer(fps=30, size=(320, 240)).start()
    port = int(server.url.split(":")[2].split("/")[0])
    config = edge_config(**{"broker.url": mosquitto.url, "camera.source": server.url})
    trackers: list[BothTrackers] = []

    def factory(inputs: TrackerInputs) -> BothTrackers:
        trackers.append(BothTrackers(inputs))
        return trackers[-1]

    try:
        with (
            caplog.at_level(logging.INFO, logger="edge"),
            MqttRecorder("127.0.0.1", mosquitto.port) as rec,
            running(config, tracker_factory=factory, calibration_loader=lambda *a: exact_calibration(camera)) as app,
        ):
            assert rec.wait_for(lambda m: len(poses(m)) >= 10)
            server.stop()
            server = MjpegServer(fps=30, port=port, size=(640, 480)).start()
            n = len(rec.messages)
            assert rec.wait_for(
                lambda m: any(s["state"] == "degraded" and s["camera"] == "missing" for s in statuses(m[n:])), 30
            )
            assert server.wait_requests(3), "several reopens at the wrong size"
            snap = app.runtime.snapshot()
            assert snap.state == "degraded" and "640x480" in snap.reason and "calibrated at 320x240" in snap.reason
            assert not app.runtime.finished and app.runtime.error is None

            server.stop()
            server = MjpegServer(fps=30, port=port, size=(320, 240)).start()
            t_back = time.time()
            n = len(rec.messages)
            assert rec.wait_for(lambda m: len([p for p in poses(m[n:]) if json.loads(p.payload)["t"] > t_back]) >= 10)
            assert rec.wait_for(lambda m: any(s["state"] == "online" for s in statuses(m[n:])), 30)
            assert app.runtime.error is None and app.runtime.capture.problem == ""
        assert trackers[0].sizes == {(320, 240)}
        said = [r for r in caplog.records if r.name == "edge.sources" and "delivers 640x480" in r.getMessage()]
        assert len(said) == 1, "said once, not at every reopen attempt"
    finally:
        server.stop()
