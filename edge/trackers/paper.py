"""The paper's pipeline as it is written, over the full frame: the baseline the windowed pipeline is measured against.

Per frame and per rover (sections IV-V): extract the rover's colour plane over the whole frame, subtract the
reference frame's plane (eq. 2), threshold with the automatic interval ``[k_max - c, k_max]`` where ``k_max`` is
the subtracted plane's maximum (Fig. 11-12), erode (P.M.O.), fill holes by reconstruction (A.M.O., Fig. 13),
take the centroid of the binary image (eq. 3-4) in pixels and map that one point to the world through the
calibration. The reference is the first frame (or the given empty scene) and is replaced whole on a timer, as in
the paper. No filter, no velocity, no heading.

The colour plane is generalised from the paper's R, G, B channels to N marker colours as the projection of the
pixel's chroma on the rover's hue (the same plane the windowed pipeline uses), so the comparison isolates what
the windowed design changes: where the work is done, how the centre is computed, and the filter.
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from edge.errors import ConfigError
from edge.segmentation import ColorModel, erode, fill_holes, opponent_planes
from edge.tracker_config import TrackerConfig
from edge.trackers.base import PlaneMapping
from edge.tracking import Frame, FrameResult, RoverEstimate, StageTimes

PAPER_THRESHOLD_SPAN = 50.0  # the constant subtracted from the maximum (8-bit plane units)
PAPER_MIN_PEAK = 25.0  # a subtracted plane whose maximum is below this shows no marker


class PaperPipeline:
    """The straightforward full-frame version of the paper's pipeline (a :class:`edge.tracking.Tracker`)."""

    def __init__(
        self, config: TrackerConfig, calibration: PlaneMapping, background: NDArray[np.uint8] | None = None
    ) -> None:
        self.config = config
        self.calibration = calibration
        try:
            self.colors = ColorModel.from_colors(
                [r.color_bgr for r in config.rovers], config.hue_tolerance_deg, config.min_saturation_fraction
            )
        except ValueError as exc:
            raise ConfigError(f"rovers: {exc}") from exc
        self._empty_scene = background
        self._period = max(1, round(config.background_refresh_s * config.fps))
        self.reset()

    def close(self) -> None:
        """Nothing runs beside the frame thread."""

    def reset(self) -> None:
        """Forget the reference: the next frame (or the empty scene) becomes it again."""
        self._reference: NDArray[np.float32] | None = None  # (N, H, W) reference planes
        self._frames = 0

    def _planes(self, image: NDArray[np.uint8]) -> NDArray[np.float32]:
        c1, c2, _ = opponent_planes(image)
        return np.stack([self.colors.plane(i, c1, c2) for i in range(len(self.config.rovers))])

    def process(self, frame: Frame) -> FrameResult:
        t_start = time.perf_counter()
        clock = StageTimes()
        image = frame.image

        t0 = time.perf_counter()
        planes = self._planes(image)  # RGB colour planes extraction
        clock.add("planes", time.perf_counter() - t0)

        t0 = time.perf_counter()
        if self._reference is None:
            self._reference = self._planes(self._empty_scene) if self._empty_scene is not None else planes.copy()
        elif self._empty_scene is None and self._frames % self._period == 0:
            self._reference = planes.copy()  # the timer: the whole reference is replaced
        clock.add("reference", time.perf_counter() - t0)

        estimates: list[RoverEstimate] = []
        missing: list[str] = []
        for i, rover in enumerate(self.config.rovers):
            t0 = time.perf_counter()
            diff = planes[i] - self._reference[i]  # eq. 2, keeping the sign (see the module docstring)
            t1 = time.perf_counter()
            clock.add("subtraction", t1 - t0)
            k_max = float(diff.max())
            mask = (diff >= k_max - PAPER_THRESHOLD_SPAN) & (diff <= k_max)
            t2 = time.perf_counter()
            clock.add("threshold", t2 - t1)
            mask = erode(mask, max(1, self.config.erosion_iterations))  # P.M.O.
            t3 = time.perf_counter()
            clock.add("erosion", t3 - t2)
            mask = fill_holes(mask)  # A.M.O.
            t4 = time.perf_counter()
            clock.add("holes", t4 - t3)
            vs, us = np.nonzero(mask)
            t5 = time.perf_counter()
            clock.add("measure", t5 - t4)
            if k_max < PAPER_MIN_PEAK or us.size == 0:
                missing.append(rover.id)
                continue
            u, v = float(us.mean()), float(vs.mean())  # eq. 3-4 on the binary image
            xy = np.asarray(self.calibration.pixel_to_world(np.array([[u, v]])), dtype=np.float64)[0]
            clock.add("calibration", time.perf_counter() - t5)
            if not np.all(np.isfinite(xy)):
                missing.append(rover.id)
                continue
            estimates.append(
                RoverEstimate(
                    rover_id=rover.id,
                    x_cm=float(xy[0]),
                    y_cm=float(xy[1]),
                    theta_rad=None,  # the paper's pipeline has no heading nor velocity
                    vx_cm_s=None,
                    vy_cm_s=None,
                    quality=1.0,
                    uv_px=(u, v),
                )
            )
        self._frames += 1
        stage_ms = clock.as_ms()
        stage_ms["total"] = (time.perf_counter() - t_start) * 1e3
        return FrameResult(frame.index, frame.t_capture_s, frame.t_mono_s, tuple(estimates), tuple(missing), stage_ms)
