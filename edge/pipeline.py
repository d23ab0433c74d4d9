"""The tracking pipeline: the windowed :class:`edge.tracking.Tracker` ``edge-ips start`` runs (``docs/tracking.md``).

1. **Acquisition** (first frame, and whenever a rover is lost): one cheap pass over a 1/4-resolution copy of the
   frame classifies pixels by hue and finds each lost rover's marker as a particle of plausible size.
2. **Tracking**: every rover that is being tracked is measured in a small full-resolution window around where its
   filter predicts it (the paper's segmentation stages, then the chosen tracker: centroid, particles or mean
   shift), to a sub-pixel, perspective-correct marker centre on the world plane.
3. **Filtering** (``edge.filtering``): a constant-velocity Kalman filter per rover gives velocity, rejects
   spikes, and follows turns.
4. **Identity** is the marker colour plus the filter's gate: a rover is only ever measured in its own colour near
   where it is expected, so crossing rovers cannot swap. A blob that is not one whole marker (area on the plane,
   shape, cut by the image border) is refused. A rover unseen in its window is reported missing (no pose) and
   after a few frames goes back to acquisition.
5. **Heading** from a two-tone marker's geometry (``edge.two_tone``: the coloured part's edges give the axis, the
   light end the front, reported only while the evidence for that end is strong), else the direction of motion
   while moving faster than ``heading_min_speed_cm_s``, else null.

No full-frame work is done per frame while all rovers are tracked, except refreshing one band of rows of the
background reference. Build one with :func:`edge.trackers.factory.build_tracker` (``method="paper"`` gives the
full-frame baseline, ``edge.trackers.paper``).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from edge.acquisition import acquisition_scale, candidates, low_resolution_view
from edge.background import BackgroundModel
from edge.blob_shape import IN_VIEW_MARGIN_PX, footprint_in_view
from edge.centre_offsets import CentreOffsets, Fits
from edge.errors import ConfigError, SourceError
from edge.filtering import FilterFactory
from edge.fit_worker import ProcessFits
from edge.rover_track import Observation, RoverTrack
from edge.segmentation import ColorModel, chroma_of_bgr
from edge.tracker_config import TrackerConfig
from edge.trackers import make_filters, make_tracker
from edge.trackers.base import Measurement, RoverModel, Window, WindowTracker, measurement_covariance
from edge.trackers.plane import PlaneGrid, PlaneMapping, world_blob
from edge.trackers.refine import refine_axis, refine_outline
from edge.trackers.window import prepare_window, window_box
from edge.tracking import Frame, FrameResult, RoverEstimate, StageTimes
from edge.two_tone import MarkerPixels, TwoToneGeometry, inner_edge_weights, view_marker
from edge.white import OBSERVE_EVERY, LocalWhite

FloatArray = NDArray[np.float64]
SIDEWAYS_MIN_SPEED_CM_S = 10.0  # motion that checks a two-tone marker's axis (edge.two_tone.TwoToneHeading.update)


class Pipeline:
    """The tracker of ``docs/tracking.md``: windowed trackers, low-resolution reacquisition, filters, identity.

    ``calibration``: the pixel <-> plane mapping (``edge.calibration.Calibration`` or any :class:`PlaneMapping`).
    ``background``: an empty-scene frame (the paper's reference), or None to learn the reference from the video.
    ``tracker``, ``acquirer``, ``filters``: the window tracker, the one that finds lost rovers and the filters'
    factory; by default those ``config`` names, with its settings (``edge.trackers.make_tracker``,
    ``make_filters``). ``fits``: where the edge fits of the ``edge_offsets`` setting run (``edge.centre_offsets``;
    by default a worker process, started on the first fit); unused without that setting.
    """

    def __init__(
        self,
        config: TrackerConfig,
        calibration: PlaneMapping,
        background: NDArray[np.uint8] | None = None,
        tracker: WindowTracker | None = None,
        *,
        acquirer: WindowTracker | None = None,
        filters: FilterFactory | None = None,
        fits: Fits | None = None,
    ) -> None:
        if config.method == "paper":
            raise ConfigError("method 'paper' is the full-frame baseline: build it with build_tracker()")
        self.config, self.calibration = config, calibration
        self.tracker = tracker if tracker is not None else make_tracker(config.method, config)
        # Acquisition always chooses among particles (by area, shape and hue), whatever tracks the rover after.
        if acquirer is None:
            acquirer = self.tracker if config.method == "particles" else make_tracker("particles", config)
        self.acquirer = acquirer
        self.filters = filters if filters is not None else make_filters(config)
        colors = [r.color_bgr for r in config.rovers]
        try:
            self.colors = ColorModel.from_colors(colors, config.hue_tolerance_deg, config.min_saturation_fraction)
        except ValueError as exc:
            raise ConfigError(f"rovers: {exc}") from exc
        self._nominal_levels = [math.hypot(*chroma_of_bgr(c)[:2]) for c in colors]
        self._empty_scene = background
        self.offsets: CentreOffsets | None = None
        if config.edge_offsets is True:  # "auto" is decided by who knows the source (TrackerConfig.for_source)
            fits = fits if fits is not None else ProcessFits(config.edge_offsets_every)
            self.offsets = CentreOffsets(fits, config.camera_sharpens)
        self.reset()

    def close(self) -> None:
        """Stop the edge fits' worker, if one was started."""
        if self.offsets is not None:
            self.offsets.close()

    def reset(self) -> None:
        """Forget every rover and the background: the next frame starts tracking afresh, at its own size."""
        self.maps: PlaneGrid | None = None
        line_time_s = self.config.line_time_us * 1e-6  # a rolling shutter (edge.rover_track)
        self.tracks = [RoverTrack(r, i, line_time_s=line_time_s) for i, r in enumerate(self.config.rovers)]
        for tr in self.tracks:
            self.tracker.reset(tr.index)
            self.acquirer.reset(tr.index)
        self.background: BackgroundModel | None = None
        self.white: LocalWhite | None = None
        self.acquire_scale = self.config.acquire_scale
        self._last_t: float | None = None
        self._frames = 0
        self._time_s = 0.0  # the stream's time: the sum of frame intervals (nominal ones where stamps are unusable)
        if self.offsets is not None:
            self.offsets.reset()

    # -- the frame loop -----------------------------------------------------------------------------------------
    def process(self, frame: Frame) -> FrameResult:
        t_start = time.perf_counter()
        clock = StageTimes()
        image = frame.image
        if self.background is None:
            self._start(image)
        assert self.background is not None
        if image.shape[:2] != self.background.shape_hw:
            h, w = self.background.shape_hw
            raise SourceError(
                f"frame {frame.index} is {image.shape[1]}x{image.shape[0]}, the stream started at {w}x{h} "
                "(the calibration and the background are for one image size)"
            )
        dt = self._dt(frame)
        self._time_s += dt

        t0 = time.perf_counter()
        for tr in self.tracks:
            if tr.filter is not None:
                tr.filter.predict(dt)
        clock.add("filter", time.perf_counter() - t0)

        if self.offsets is not None:
            t0 = time.perf_counter()
            self.offsets.start_frame(self._frames, self.tracks)
            clock.add("offsets", time.perf_counter() - t0)

        measured: dict[int, Observation] = {}
        for tr in self.tracks:
            if tr.filter is None:
                continue
            m = self._track(image, tr, clock)
            if m is not None:
                measured[tr.index] = m
            else:
                tr.misses += 1
                if tr.misses >= self.config.lost_after_frames:
                    self._lose(tr)

        acquired: dict[int, Observation] = {}
        if any(tr.lost for tr in self.tracks):
            acquired = self._acquire(image, clock)

        estimates = self._estimates(measured, acquired, clock)

        t0 = time.perf_counter()
        exclude = [self._exclusion_box(tr.box, image.shape) for tr in self.tracks if tr.box is not None]
        rows = self.background.refresh(image, exclude)
        if self.white is None:
            self.white = LocalWhite(self.background.reference, self.background.valid)
        else:
            self.white.update(self.background.reference, self.background.valid, rows)  # the light follows it
            if self._frames % OBSERVE_EVERY == 0:  # and the whole view's change, for the next frames' windows
                self.white.observe(image, self.background.reference, self.background.valid)
        clock.add("reference", time.perf_counter() - t0)

        self._frames += 1
        seen = {e.rover_id for e in estimates}
        missing = tuple(tr.config.id for tr in self.tracks if tr.config.id not in seen)
        stage_ms = clock.as_ms()
        stage_ms["total"] = (time.perf_counter() - t_start) * 1e3
        return FrameResult(frame.index, frame.t_capture_s, frame.t_mono_s, estimates, missing, stage_ms)

    def _start(self, image: NDArray[np.uint8]) -> None:
        h, w = image.shape[:2]
        if self._empty_scene is not None and self._empty_scene.shape[:2] != (h, w):
            eh, ew = self._empty_scene.shape[:2]
            raise ConfigError(f"background image is {ew}x{eh} but the frames are {w}x{h}")
        self.maps = PlaneGrid(self.calibration, (w, h))
        period = max(1, round(self.config.background_refresh_s * self.config.fps))
        self.background = BackgroundModel((h, w), period, self._empty_scene)
        self.white = LocalWhite(self._empty_scene, np.ones((h, w), bool)) if self._empty_scene is not None else None
        self.acquire_scale = acquisition_scale(
            self.config.marker_area_cm2, self.config.acquire_scale, self.maps, self.calibration
        )

    def _dt(self, frame: Frame) -> float:
        nominal = 1.0 / self.config.fps
        last, self._last_t = self._last_t, frame.t_capture_s
        if last is None:
            return nominal
        dt = frame.t_capture_s - last
        return dt if 0.0 < dt < 5.0 else nominal

    # -- tracking in a window -----------------------------------------------------------------------------------
    def _track(self, image: NDArray[np.uint8], tr: RoverTrack, clock: StageTimes) -> Observation | None:
        assert tr.filter is not None
        x, y = tr.filter.position
        sigma = min(tr.filter.position_sigma_cm, 30.0)
        radius = self.config.marker_radius_cm + self.config.window_margin_cm + 3.0 * sigma
        t0 = time.perf_counter()
        box, uv = self._window_box((x, y), radius, image.shape, tr.uv)
        clock.add("window", time.perf_counter() - t0)
        tr.box = box
        if box is None:
            return None
        obs = self._measure(image, tr, box, uv, clock)
        return None if obs is None else tr.at_frame_time(obs)

    def _window_box(
        self, xy_cm: tuple[float, float], radius_cm: float, shape: tuple[int, ...], hint_uv: tuple[float, float] | None
    ) -> tuple[tuple[int, int, int, int] | None, tuple[float, float]]:
        assert self.maps is not None
        return window_box(self.maps, self.calibration, xy_cm, radius_cm, shape, hint_uv)

    def _measure(
        self,
        image: NDArray[np.uint8],
        tr: RoverTrack,
        box: tuple[int, int, int, int],
        uv: tuple[float, float],
        clock: StageTimes,
        tracker: WindowTracker | None = None,
    ) -> Observation | None:
        assert self.background is not None and self.maps is not None
        window = prepare_window(
            image,
            box,
            rover_index=tr.index,
            predicted_uv=uv,
            colors=self.colors,
            maps=self.maps,
            background=self.background,
            background_threshold=self.config.background_threshold,
            clock=clock,
            white=self.white,
            others=[t.box for t in self.tracks if t is not tr and t.box is not None],
            unseen_since=None if tr.filter is not None else tr.lost_at or 0,
        )
        if window is None:
            return None
        model = RoverModel(tr.index, tr.expected_area(self.config.marker_area_cm2), tr.level)
        m = (tracker or self.tracker).measure(window, model, clock)
        if m is None:
            return None
        jac = window.local.jacobian(*m.uv_px)  # the refinements keep the image centroid: one Jacobian for all
        if tr.config.front_color_bgr is None:
            t0 = time.perf_counter()
            size = (self.config.marker_length_cm, self.config.marker_width_cm)
            refine = refine_outline if self.config.outline_fit else refine_axis
            m = refine(window, m, size, tr.index, jacobian=jac)
            if m.at_image_edge and footprint_in_view(
                window.local.to_pixel, m.xy_cm, m.axis_rad, size, window.image_size, IN_VIEW_MARGIN_PX
            ):
                m = replace(m, at_image_edge=False)  # whole: only its blurred edge reaches the border
            clock.add("outline", time.perf_counter() - t0)
        if not tr.whole_marker(
            m, model.marker_area_cm2, tr.learned, self.config, self._nominal_levels[tr.index], self._frames, jac
        ):
            return None
        if tr.config.front_color_bgr is not None:
            two_tone = self._two_tone(window, m, tr, jac)
            if two_tone is None:
                return None  # without a heading the centre of a two-tone marker is not known
            m = two_tone
        elif self.offsets is not None:
            assert self.maps is not None
            t0 = time.perf_counter()
            size = (self.config.marker_length_cm, self.config.marker_width_cm)
            m = self.offsets.corrected(window, m, tr, self.maps, size)  # edge.centre_offsets
            clock.add("offsets", time.perf_counter() - t0)
        return Observation(m, measurement_covariance(jac, self.config.measurement_sigma_px))

    def _two_tone(self, window: Window, m: Measurement, tr: RoverTrack, jacobian: FloatArray) -> Measurement | None:
        """A two-tone marker (``edge.two_tone``): the heading from the coloured part's edges and the light end, and
        the marker's centre (the coloured part covers only the rear ``1 - front_fraction`` of the marker, so its
        centroid lies ``front_fraction * length / 2`` behind the centre, along the heading).

        Returns the measurement moved to the marker's centre (the heading to report is in ``tr.two_tone``); None
        when the heading is unknown even roughly (no pose this frame: the centre is not known). ``jacobian``: the
        plane mapping's at the measurement's image centroid.
        """
        assert self.maps is not None
        x0, y0, x1, y1 = window.box
        wx, wy = self.maps.x_cm[y0:y1, x0:x1], self.maps.y_cm[y0:y1, x0:x1]
        others = (window.classes >= 0) & (window.classes != tr.index)
        reach = self.config.marker_radius_cm + 1.0
        for other in self.tracks:
            if other is tr or other.filter is None:
                continue
            ox, oy = other.filter.position
            if abs(ox - m.xy_cm[0]) < 3.0 * reach and abs(oy - m.xy_cm[1]) < 3.0 * reach:
                others |= (wx - ox) ** 2 + (wy - oy) ** 2 <= reach * reach
        geometry = TwoToneGeometry(self.config.marker_length_cm, self.config.marker_width_cm, tr.config.front_fraction)
        pixels = MarkerPixels(
            bgr=window.bgr,
            lum=window.lum,
            plane=window.plane,
            own=window.classes == tr.index,
            x_cm=wx,
            y_cm=wy,
            others=others,
            coverage=m.weights,
            area_cm2=self.maps.area_cm2[y0:y1, x0:x1],
        )
        view = view_marker(pixels, m.xy_cm, jacobian, geometry)
        heading = tr.two_tone.update(view, self._time_s, self._motion_rad(tr))
        if heading is None:
            return None
        part = m.xy_cm
        if view is not None and tr.two_tone.confident and m.weights is not None:
            weights = inner_edge_weights(window.bgr, m.weights, wx, wy, part, heading, geometry, jacobian)
            blob = world_blob(weights, window.offset, window.grid) if weights is not None else None
            if blob is not None:
                part = (blob.x_cm, blob.y_cm)
        shift = geometry.centre_offset_cm
        centre = (part[0] + shift * math.cos(heading), part[1] + shift * math.sin(heading))
        return replace(m, xy_cm=centre)

    def _motion_rad(self, tr: RoverTrack) -> float | None:
        """The direction the rover moves, when it moves clearly (a check on a two-tone marker's axis)."""
        vel = tr.filter.velocity if tr.filter is not None else None
        if vel is None or math.hypot(*vel) < SIDEWAYS_MIN_SPEED_CM_S:
            return None
        return math.atan2(vel[1], vel[0])

    # -- acquisition (low resolution) ---------------------------------------------------------------------------
    def _acquire(self, image: NDArray[np.uint8], clock: StageTimes) -> dict[int, Observation]:
        """Find lost rovers from a 1/``acquire_scale`` resolution pass (``edge.acquisition``), then measure them at
        full resolution."""
        assert self.background is not None
        t0 = time.perf_counter()
        s = self.acquire_scale
        view = low_resolution_view(image, s, self.colors, self.white)
        clock.add("acquire", time.perf_counter() - t0)
        found: dict[int, Observation] = {}
        # Where the tracked rovers are: a candidate there is another rover's marker seen in a confusable hue.
        taken = [tr.filter.position for tr in self.tracks if tr.filter is not None]
        slack = self.config.marker_radius_cm + self.config.window_margin_cm
        for tr in self.tracks:
            if tr.filter is not None:
                continue
            t1 = time.perf_counter()
            places = candidates(view, tr.index, self.colors)
            clock.add("acquire", time.perf_counter() - t1)
            for u, v in places:
                xy = self.calibration.pixel_to_world(np.array([[u, v]]))[0]
                if not np.all(np.isfinite(xy)):
                    continue
                if any(math.hypot(xy[0] - p[0], xy[1] - p[1]) < self.config.marker_radius_cm for p in taken):
                    continue
                speed = self.config.max_speed_cm_s
                if speed is not None and not tr.within_reach((float(xy[0]), float(xy[1])), self._time_s, speed, slack):
                    continue  # farther than the rover could have driven since it was last seen: not it
                radius = self.config.marker_radius_cm + self.config.window_margin_cm + 2.0 * s
                box, _ = self._window_box((float(xy[0]), float(xy[1])), radius, image.shape, (u, v))
                if box is None:
                    continue
                self.tracker.reset(tr.index)
                m = self._measure(image, tr, box, (u, v), clock, self.acquirer)
                if m is None:
                    continue
                tr.box = box
                found[tr.index] = m
                self.background.forget(box, tr.lost_at or 0, m.measurement.weights)  # copied while it was lost
                taken.append(m.measurement.xy_cm)
                break
        return found

    def _lose(self, tr: RoverTrack) -> None:
        tr.filter = None
        tr.lost_at = self._frames
        tr.box = tr.uv = tr.theta_rad = None
        tr.heading.reset()
        tr.two_tone.reset()
        self.tracker.reset(tr.index)

    # -- filtering, identity, heading ---------------------------------------------------------------------------
    def _estimates(
        self, measured: dict[int, Observation], acquired: dict[int, Observation], clock: StageTimes
    ) -> tuple[RoverEstimate, ...]:
        """Fuse this frame's measurements into the filters (new filters for rovers just acquired)."""
        t0 = time.perf_counter()
        out: list[RoverEstimate] = []
        for tr in self.tracks:
            if tr.index in acquired:
                obs = acquired[tr.index]
                m = obs.measurement
                tr.filter = self.filters.create_filter(m.xy_cm, obs.r_cm2)
                tr.lost_at = None
                if tr.relearned_at == self._frames:
                    tr.forget_sizes()  # taken by RoverTrack.relearn: learned afresh from here, as when first seen
            elif tr.index in measured and tr.filter is not None:
                obs = measured[tr.index]
                m = obs.measurement
                if not tr.filter.update(np.asarray(m.xy_cm), obs.r_cm2):
                    tr.misses += 1  # a spike: rejected, no pose this frame
                    if tr.misses >= self.config.lost_after_frames:
                        self._lose(tr)
                    continue
            else:
                continue
            assert tr.filter is not None
            if self.offsets is not None:
                self.offsets.filtered(tr, obs.ahead_cm)
            tr.misses = 0
            tr.uv = m.uv_px
            tr.seen = (m.xy_cm[0], m.xy_cm[1], self._time_s)
            tr.level = m.level if tr.level <= 0.0 else 0.8 * tr.level + 0.2 * m.level
            tr.learn(m, self.config.marker_area_cm2, self._frames)
            theta = self._heading(tr, tr.filter.clear_velocity(), m)
            out.append(tr.estimate(obs, theta, round(self._quality(tr, m), 2)))
        clock.add("filter", time.perf_counter() - t0)
        return tuple(out)

    @staticmethod
    def _quality(tr: RoverTrack, m: Measurement) -> float:
        """The measurement's quality; for a two-tone marker scaled down (to half) while the evidence for which end
        is its front is weak, since the centre is placed by that end."""
        if tr.config.front_color_bgr is None:
            return m.quality
        return m.quality * (0.5 + 0.5 * min(1.0, max(0.0, tr.two_tone.evidence)))

    def _heading(self, tr: RoverTrack, vel: tuple[float, float] | None, m: Measurement) -> float | None:
        """A two-tone marker's own heading while the evidence for its front end is strong (else None: the direction
        of motion is the opposite of the body's when the rover backs up); for a one-colour marker its long axis
        through its heading filter (``edge.filtering.one_colour_heading``), by the marker's size in the image."""
        if tr.config.front_color_bgr is not None:
            return tr.two_tone.heading_rad if tr.two_tone.confident else None
        square = abs(self.config.marker_length_cm - self.config.marker_width_cm) < 0.05 * self.config.marker_length_cm
        assert self.maps is not None
        px = self.maps.pixels_of(self.config.marker_area_cm2, *m.uv_px)
        return tr.one_colour_heading(m, square, vel, self.config.heading_min_speed_cm_s, self._time_s, px)

    def _exclusion_box(self, box: tuple[int, int, int, int], shape: tuple[int, ...]) -> tuple[int, int, int, int]:
        """The search window grown to cover the rover's body below and around the marker."""
        x0, y0, x1, y1 = box
        gw, gh = (x1 - x0) // 2, (y1 - y0) // 2
        return max(0, x0 - gw), max(0, y0 - gh), min(shape[1], x1 + gw), min(shape[0], y1 + 2 * gh)
