"""Offline tracking: a video file in, pose v1 JSON lines out (``edge-ips track``).

Every line is exactly the bytes the runtime would publish for that rover and frame (``edge.messages.encode_pose``);
with ``--detections``, one detections v1 line per frame instead (what a board of several publishes for the fusion).
Frames carry the video's own clock: ``t`` is the frame's position in the video in seconds (a file has no wall-clock
capture time), so poses from one video are comparable across runs.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from edge.calibration import load_calibration
from edge.errors import CalibrationError, ConfigError, SourceError
from edge.fusion.detections import encode_detections
from edge.fusion.uncertainty import DetectionBuilder, calibration_error_model
from edge.messages import encode_pose
from edge.pooled_fits import PooledFits
from edge.tracker_config import TrackerConfig
from edge.trackers.base import CameraPlaneMapping, PlaneMapping
from edge.trackers.factory import build_tracker
from edge.tracking import Frame, FrameResult, Tracker


@dataclass
class TrackSummary:
    """What a run of the tracker over a video did."""

    frames: int = 0
    rovers: tuple[str, ...] = ()
    poses: int = 0
    per_rover: dict[str, int] = field(default_factory=dict)
    processing_s: float = 0.0
    wall_s: float = 0.0
    stage_ms_median: dict[str, float] = field(default_factory=dict)

    @property
    def processing_fps(self) -> float:
        """Frames per second of the tracker alone (after decode)."""
        return self.frames / self.processing_s if self.processing_s > 0 else 0.0

    @property
    def wall_fps(self) -> float:
        """Frames per second including decoding and writing."""
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def detection_rate(self) -> float:
        """Poses written over rover-frames."""
        total = self.frames * len(self.rovers)
        return self.poses / total if total else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "poses": self.poses,
            "detection_rate": round(self.detection_rate, 4),
            "processing_fps": round(self.processing_fps, 1),
            "wall_fps": round(self.wall_fps, 1),
            "per_rover": self.per_rover,
            "stage_ms_median": {k: round(v, 3) for k, v in self.stage_ms_median.items()},
        }


def load_plane_mapping(path: Path, expected_size: tuple[int, int]) -> PlaneMapping:
    """The calibration in ``path``: an ``edge-ips/calibration`` file, or a ``camera.json`` of a known camera.

    Raises :class:`CalibrationError` naming the file when it cannot be read or is for another image size.
    """
    try:
        head = json.loads(path.read_text())
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read calibration file ({exc.strerror})") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: not a calibration file (malformed JSON: {exc})") from exc
    kind = head.get("kind") if isinstance(head, dict) else None
    if kind == "edge-ips/camera":
        from edge.camera import MARKER_HEIGHT_CM, load_camera

        camera = load_camera(path)
        if (camera.width_px, camera.height_px) != expected_size:
            raise CalibrationError(
                f"{path}: camera is for {camera.width_px}x{camera.height_px} images, "
                f"the video is {expected_size[0]}x{expected_size[1]}"
            )
        return CameraPlaneMapping(camera, MARKER_HEIGHT_CM)
    return load_calibration(path, expected_size=expected_size)


def read_background(path: Path, expected_size: tuple[int, int]) -> NDArray[np.uint8]:
    """An empty-scene frame (the paper's reference) of the video's size."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SourceError(f"{path}: cannot read background image")
    h, w = image.shape[:2]
    if (w, h) != expected_size:
        raise ConfigError(f"{path}: background is {w}x{h}, the video is {expected_size[0]}x{expected_size[1]}")
    return np.asarray(image, dtype=np.uint8)


class VideoFrames:
    """Frames of a video file (anything OpenCV reads), timestamped with the video's own clock."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if not path.is_file():
            raise SourceError(f"{path}: no such video file")
        self._cap = cv2.VideoCapture(str(path))
        if not self._cap.isOpened():
            raise SourceError(f"{path}: cannot open video (not a format OpenCV reads)")
        ok, first = self._cap.read()
        if not ok or first is None:
            self._cap.release()
            raise SourceError(f"{path}: cannot read a frame from the video")
        self._first: NDArray[np.uint8] | None = np.asarray(first, dtype=np.uint8)
        fps = float(self._cap.get(cv2.CAP_PROP_FPS))
        self.fps = fps if 0.0 < fps < 1000.0 else 30.0
        self.frame_count = max(0, int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT)))
        self.size = (first.shape[1], first.shape[0])

    def __iter__(self) -> Iterator[Frame]:
        index = 0
        t0 = time.monotonic()
        while True:
            if self._first is not None:
                image, self._first = self._first, None
            else:
                ok, raw = self._cap.read()
                if not ok or raw is None:
                    return
                image = np.asarray(raw, dtype=np.uint8)
            t = index / self.fps
            yield Frame(image=image, index=index, t_capture_s=t, t_mono_s=t0 + t)
            index += 1

    def close(self) -> None:
        self._cap.release()


@dataclass
class TrackJob:
    """A video opened and a tracker built for it: everything checked before the first frame is tracked."""

    frames: VideoFrames
    tracker: Tracker
    rovers: tuple[str, ...]
    mapping: PlaneMapping

    def run(
        self,
        out: Path,
        on_frame: Callable[[FrameResult], None] | None = None,
        detections: DetectionBuilder | None = None,
    ) -> TrackSummary:
        """Track every frame; write one pose v1 line per rover per frame where it was seen to ``out``, or with
        ``detections`` one detections v1 line per frame (the board's measurements, for ``edge-ips fuse``). The tracker
        is closed after (the edge fits' worker processes stopped)."""
        summary = TrackSummary(rovers=self.rovers, per_rover=dict.fromkeys(self.rovers, 0))
        seq = dict.fromkeys(self.rovers, 0)
        stages: dict[str, list[float]] = {}
        t_wall = time.perf_counter()
        try:
            handle = out.open("wb")
        except OSError as exc:
            raise ConfigError(f"{out}: cannot write poses ({exc.strerror})") from exc
        try:
            with handle:
                for frame in self.frames:
                    t0 = time.perf_counter()
                    result = self.tracker.process(frame)
                    summary.processing_s += time.perf_counter() - t0
                    summary.frames += 1
                    for name, ms in result.stage_ms.items():
                        stages.setdefault(name, []).append(ms)
                    if detections is not None:
                        # offline, the message leaves when the frame is captured: the video's clock has no other
                        board = detections.build(result, frame.image, t_sent_s=frame.t_capture_s)
                        handle.write(encode_detections(board) + b"\n")
                    for e in result.estimates:
                        summary.per_rover[e.rover_id] += 1
                        summary.poses += 1
                        if detections is not None:
                            continue
                        line = encode_pose(
                            e.rover_id,
                            seq[e.rover_id],
                            frame.index,
                            frame.t_capture_s,
                            e.x_cm,
                            e.y_cm,
                            e.theta_rad,
                            e.vx_cm_s,
                            e.vy_cm_s,
                            e.quality,
                        )
                        handle.write(line + b"\n")
                        seq[e.rover_id] += 1
                    if on_frame is not None:
                        on_frame(result)
        finally:
            try:
                self.frames.close()
            finally:
                self.tracker.close()  # the edge fits' workers
        summary.wall_s = time.perf_counter() - t_wall
        summary.stage_ms_median = {k: float(np.median(v)) for k, v in stages.items()}
        return summary


def open_track_job(video: Path, calibration: Path, config: TrackerConfig, background: Path | None = None) -> TrackJob:
    """Open ``video``, load the calibration (checked against the video's size) and build the tracker."""
    frames = VideoFrames(video)
    try:
        mapping = load_plane_mapping(calibration, frames.size)
        empty = read_background(background, frames.size) if background is not None else None
        # a video file's frames came through a codec (edge_offsets auto: on); the edge fits run in worker processes
        # on the in-loop schedule (each result taken at a set frame, waited for if need be), so a video's poses come
        # out the same on every run while the frame loop runs on beside the fits
        config = config.for_source(chroma_spread=True)
        fits = PooledFits(config.edge_offsets_every) if config.edge_offsets else None
        tracker = build_tracker(config, mapping, empty, fits=fits)
    except BaseException:
        frames.close()
        raise
    return TrackJob(frames, tracker, tuple(r.id for r in config.rovers), mapping)


def track_video(
    video: Path,
    calibration: Path,
    out: Path,
    config: TrackerConfig,
    background: Path | None = None,
    on_frame: Callable[[FrameResult], None] | None = None,
) -> TrackSummary:
    """Track every frame of ``video`` into pose JSON lines in ``out`` (:func:`open_track_job` then run it)."""
    return open_track_job(video, calibration, config, background).run(out, on_frame)


def detection_builder(job: TrackJob, calibration: Path, edge_id: str) -> DetectionBuilder:
    """The builder of ``job``'s detections messages as board ``edge_id``, with the error model of ``calibration``."""
    from edge.calibration.files import Calibration

    area = job.mapping.area_cm if isinstance(job.mapping, Calibration) else None
    return DetectionBuilder(edge_id, job.mapping, calibration_error_model(calibration), job.frames.size, area)


def board_id_for(video: Path, edge_id: str | None) -> str:
    """``edge_id`` when given (checked), else the video's directory name when it is a valid id, else ``edge-1``."""
    import re

    from edge.messages import ID_PATTERN

    if edge_id is not None:
        if not re.match(ID_PATTERN, edge_id):
            raise ConfigError(f"--edge-id {edge_id!r}: use 1-16 characters of a-z, 0-9, _ and -")
        return edge_id
    parent = video.resolve().parent.name
    return parent if re.match(ID_PATTERN, parent) else "edge-1"
