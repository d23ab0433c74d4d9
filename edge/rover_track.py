"""What the pipeline keeps about one rover between frames, and a measurement that passed its checks."""

from __future__ import annotations

import itertools
import math
import statistics
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from edge.area_checks import LEARN_SPAN, back_to_nominal, nominal_below, steady_areas, symmetric_below
from edge.blob_shape import point_asymmetry, wear_stretch
from edge.filtering import ConstantVelocityFilter, HeadingFilter, one_colour_heading
from edge.tracker_config import RoverConfig, TrackerSettings
from edge.trackers.base import Measurement
from edge.tracking import RoverEstimate
from edge.two_tone import TwoToneHeading

FloatArray = NDArray[np.float64]
LOWEST_AREA_FRACTION = 0.75  # no evidence but the area makes a blob showing less than this share a whole marker
STEADY_FRAMES = 8  # the consecutive frames whose areas show a whole marker's area level (steady_areas)
STEADY_SLOPE = 0.01  # the most those areas may rise or fall per frame, as a share of the learned area
STEADY_STEP = 0.06  # the most the last area may differ from the median of the frames before it (same share)
STEADY_SCATTERS = 5.0  # a steady area may lie this many of the rover's own area scatters below its learned area
RELEARN_FRAMES = 60  # lost this long (2 s at 30 fps), a rover may learn its area afresh (RoverTrack.relearn)
RELEARN_NEARER = 1.1  # ... from a blob nearer the nominal area than its learned area is, by this factor
RELEARN_SHAPE = 0.07  # ... whose elongation is within this share of the marker's aspect (a hidden end shortens it)
RELEARN_STEP_CM = 3.0  # ... and whose last frames' blobs each lay within this of the next (one blob, not several)
CORE_BAND = 0.06  # a blob whose binary core shows its learned core's area within this share is whole (core_whole)
CORES_KNOWN = 10  # whole blobs' cores learned before a rover's core is known (before it, every one is learned)
CORE_OVER = 1.25  # a blob's core over this share of the learned core is not learned (RoverTrack.learn)
CORE_JOINED = 1.3  # a lost rover's blob whose core is over this share of it holds more than its marker (core_joined)
SEEN_FRAMES = 60  # lost this long at most, a rover is expected where it was last seen (area_checks.SYMMETRY_STEP_CM)
LOPSIDED_RATIO = 0.98  # a blob below this share of the learned area, more lopsided than the rover's whole marker ...
LOPSIDED_FLOOR = 0.2  # ... is (twice the median point asymmetry of its whole blobs, plus 0.1; at least this) ...
LOPSIDED_UNKNOWN = 0.4  # ... or than this before that is known, has a part hidden (RoverTrack.lopsided_limit)
SKEW_PX = 400.0  # whole blobs' asymmetries are learned scaled to this many pixels (RoverTrack.lopsided_limit)
SKEW_EVERY = 3  # a whole blob's point asymmetry is learned in one frame of this many
JOINED_RATIO = 1.05  # a blob this much larger than the learned area, lopsided beyond JOINED_SKEW (point asymmetry)
JOINED_SKEW = 0.35  # and farther than JOINED_STEP_CM from the filter's prediction is the marker joined to something
JOINED_STEP_CM = 1.5  # of its hue that could not be parted off (edge.blob_shape.marker_part)


@dataclass(frozen=True)
class Observation:
    """A measurement that passed the pipeline's checks, with its covariance on the plane (cm^2). ``ahead_cm``: how
    far the rover had moved on from the frame's time when its row was exposed (a rolling shutter), taken off
    ``measurement`` (:meth:`RoverTrack.at_frame_time`)."""

    measurement: Measurement
    r_cm2: FloatArray
    ahead_cm: tuple[float, float] = (0.0, 0.0)


@dataclass
class RoverTrack:
    """The pipeline's mutable state for one rover."""

    config: RoverConfig
    index: int
    filter: ConstantVelocityFilter | None = None
    line_time_s: float = 0.0  # the camera's rolling shutter (TrackerSettings.line_time_us)
    misses: int = 0
    level: float = 0.0
    areas: deque[float] = field(default_factory=lambda: deque(maxlen=31))
    cores: deque[float] = field(default_factory=lambda: deque(maxlen=31))  # the binary cores' areas of whole blobs
    # whole blobs' point asymmetry, every SKEW_EVERY frames over the last 10 s at 30 fps (a part hidden a little more
    # each second barely moves their median)
    skews: deque[float] = field(default_factory=lambda: deque(maxlen=100))
    # (frame, area, where): the blob measured in each of the last frames, where None if not known
    sizes: deque[tuple[int, float, tuple[float, float] | None]] = field(
        default_factory=lambda: deque(maxlen=STEADY_FRAMES)
    )
    box: tuple[int, int, int, int] | None = None
    uv: tuple[float, float] | None = None
    theta_rad: float | None = None
    heading: HeadingFilter = field(default_factory=HeadingFilter)  # a one-colour marker's heading through time
    two_tone: TwoToneHeading = field(default_factory=TwoToneHeading)  # a two-tone marker's heading through time
    seen: tuple[float, float, float] | None = None  # where (cm) and when (s, the stream's time) it was last measured
    offset_cm: tuple[float, float] = (0.0, 0.0)  # the centre correction last applied (edge.centre_offsets)
    lost_at: int | None = None  # the frame it was lost in (None while tracked, or before it was first seen)
    relearned_at: int | None = None  # the frame a blob was taken by :meth:`relearn` (its areas to be forgotten)

    @property
    def lost(self) -> bool:
        return self.filter is None

    @property
    def learned(self) -> bool:
        """Enough whole-marker areas seen to know this rover's own marker area."""
        return len(self.areas) >= 10

    def one_colour_heading(
        self,
        m: Measurement,
        square: bool,
        velocity_cm_s: tuple[float, float] | None,
        min_speed_cm_s: float,
        t_s: float,
        marker_px: float,
    ) -> float | None:
        """This rover's heading from its one-colour marker's measurement ``m`` (``edge.filtering.one_colour_heading``;
        no axis when the marker is ``square``), its edges weighed by the marker's size in the image (``marker_px``)
        and the direction of motion by its filter's scatter across it."""
        motion_sigma = self.filter.direction_sigma_rad() if self.filter is not None else 0.0
        axis = None if square else m.axis_rad
        self.theta_rad = one_colour_heading(
            self.heading,
            axis,
            m.axis_coherence,
            velocity_cm_s,
            self.theta_rad,
            min_speed_cm_s,
            t_s,
            marker_px,
            motion_sigma,
        )
        return self.theta_rad

    def expected_area(self, nominal_cm2: float) -> float:
        """The marker area to expect: the median of this rover's recent areas once learned, within half to twice
        the nominal one."""
        if self.learned:
            learned = float(statistics.median(self.areas))  # 31 floats: plain Python is quicker
            return min(max(learned, 0.5 * nominal_cm2), 2.0 * nominal_cm2)
        return nominal_cm2

    def area_band(
        self, expected_cm2: float, min_fraction: float, max_fraction: float, scatters: float = 3.0
    ) -> tuple[float, float]:
        """The accepted blob area, as a share of the learned one: ``min_fraction``..``max_fraction``, widened to
        ``scatters`` (three: the upper end always) robust standard deviations of this rover's own recent areas (a
        compressed stream's far-side areas scatter by 10 %; a marker a leg hides loses far more); the scatter widens
        the lower end to :data:`LOWEST_AREA_FRACTION` at most, ``min_fraction`` below that lowers it further.

        The scatter is the larger of the areas' absolute deviations' median and that of the deviations above the
        learned area: areas below the band are never learned, so the scatter below it looks smaller than the
        stream's (and the band, cut there, stays too narrow); above it nothing is cut and a hidden part adds
        nothing."""
        deviations = [a - expected_cm2 for a in self.areas]
        above = [d for d in deviations if d > 0.0]
        mad = max(statistics.median(map(abs, deviations)), statistics.median(above) if above else 0.0)
        spread = 1.4826 * float(mad) / expected_cm2
        low = min(min_fraction, max(1.0 - scatters * spread, LOWEST_AREA_FRACTION))
        return low, max(max_fraction, 1.0 + 3.0 * spread)

    def learn(self, m: Measurement, nominal_cm2: float, frame: int) -> None:
        """Learn the areas of a blob taken for this rover: its area when it is near the learned one (its quality) or
        larger and level (:meth:`larger_and_level`) or, the learned area grown past :data:`LEARN_SPAN` of the nominal
        one, within it (``edge.area_checks.back_to_nominal``); its binary core's when near the learned core (or
        none yet)."""
        if (
            m.quality > 0.8
            or self.larger_and_level(m.area_cm2, nominal_cm2, frame)
            or back_to_nominal(m.area_cm2 / nominal_cm2, self.expected_area(nominal_cm2) / nominal_cm2)
        ):
            self.areas.append(m.area_cm2)
        if m.core_cm2 > 0.0 and (
            len(self.cores) < CORES_KNOWN or 0.8 <= m.core_cm2 / statistics.median(self.cores) <= CORE_OVER
        ):
            self.cores.append(m.core_cm2)

    def forget_sizes(self) -> None:
        """Forget the learned areas and cores (a blob taken by :meth:`relearn`: learned afresh from it)."""
        self.areas.clear()
        self.cores.clear()

    def core_joined(self, m: Measurement, frame: int) -> bool:
        """Is a blob taken to find this rover again, lost for under :data:`RELEARN_FRAMES` (its core learned in the
        light it still stands in), joined to something of its hue: its binary core over :data:`CORE_JOINED` of the
        learned one? A whole marker's core stayed within 0.95-1.19 of it through sun and shade. The family's
        occlusion clip on wood (seed 14641): a person's red clothes beside the red marker made one blob of 1.14 of
        its area, symmetric (point asymmetry 0.13) and no longer than a marker may be, 13 cm from the rover; its core
        was 1.44 of the learned one. With no prediction to check it by, it was taken."""
        if self.filter is not None or self.lost_at is None or frame - self.lost_at >= RELEARN_FRAMES:
            return False
        core = self.core_ratio(m)
        return core is not None and core > CORE_JOINED

    def core_ratio(self, m: Measurement) -> float | None:
        """The blob's binary core as a share of the learned core (None: no core measured, or not known yet)."""
        if m.core_cm2 <= 0.0 or len(self.cores) < CORES_KNOWN:
            return None
        return m.core_cm2 / statistics.median(self.cores)

    def core_whole(self, m: Measurement, ratio: float, config: TrackerSettings) -> bool:
        """Is a blob whose area is ``ratio`` of the learned one, outside the area band, whole by its binary core? The
        core's area at least 1 - :data:`CORE_BAND` of the rover's learned core area and at most that much over it
        (``max_area_fraction`` over it for an area below the band); the lopsided and joined checks follow as for any
        blob. The unmixed area rests on the surround's colours; where they fail (a body's sky-lit white top face
        round the marker, brighter than all of them) it fell to 0.65 of a whole marker's while the core stayed at
        0.95-1.19 of the core learned in the sun; a part hidden takes both down (docs/tracking.md, "Is it one whole
        marker?")."""
        core = self.core_ratio(m)
        return core is not None and 1.0 - CORE_BAND <= core <= (
            config.max_area_fraction if ratio < 1.0 else 1.0 + CORE_BAND
        )

    def measured(self, frame: int, area_cm2: float, xy_cm: tuple[float, float] | None = None) -> None:
        """Note the area (and where, ``xy_cm``) of the blob measured for this rover in ``frame`` (whole or not; the
        last one of a frame)."""
        if self.sizes and self.sizes[-1][0] == frame:
            self.sizes.pop()
        self.sizes.append((frame, area_cm2, xy_cm))

    def one_blob(self, step_cm: float) -> bool:
        """Did the blobs of the frames in :meth:`steady`'s history each lie within ``step_cm`` of the next (one blob
        followed, not several measured in turn, as the search for a lost rover may)?"""
        places = [xy for _, _, xy in self.sizes if xy is not None]
        if len(places) < len(self.sizes):
            return False
        return all(math.dist(a, b) <= step_cm for a, b in itertools.pairwise(places))

    def steady(self, frame: int, expected_cm2: float) -> bool:
        """Have the blobs of the last :data:`STEADY_FRAMES` frames up to ``frame`` (each measured, none missed) shown
        one level of area (:func:`steady_areas`)?"""
        if len(self.sizes) < STEADY_FRAMES or self.sizes[0][0] != frame - STEADY_FRAMES + 1:
            return False
        return steady_areas([a / expected_cm2 for _, a, _ in self.sizes], STEADY_SLOPE, STEADY_STEP)

    def larger_and_level(self, area_cm2: float, nominal_cm2: float, frame: int) -> bool:
        """Is an accepted blob larger than the learned area and its area level over the last frames
        (:meth:`steady`)? Then it is learned whatever its quality (its share of the learned area).

        A blob is learned when its area is within a quarter of the learned one; a marker first seen with a fifth of it
        hidden (parked against a box's edge) has its area learned that small, and once uncovered shows 1.28 of it:
        taken (within the band), never learned, its quality 0.78 for good. A hidden part only makes a blob smaller,
        so one that is larger and level is the whole marker, and the learned area follows it; a smaller one is not
        learned below the quarter (a leg standing on the marker would draw the band down after it)."""
        expected = self.expected_area(nominal_cm2)
        return self.learned and area_cm2 > expected and self.steady(frame, expected)

    def whole_marker(
        self,
        m: Measurement,
        expected_area_cm2: float,
        learned: bool,
        config: TrackerSettings,
        nominal_level: float,
        frame: int,
        cm_per_px: FloatArray | None = None,
    ) -> bool:
        """Is this blob the rover's whole marker? Its area on the plane, its shape, its colour's strength, and not cut
        off by the image border (``edge.pipeline``; ``nominal_level``: the configured colour's level in its plane,
        ``frame``: the frame's number, for the areas' history; ``cm_per_px``: the plane's Jacobian at the marker,
        for the shape a stream's wear in pixels gives it there).

        A partly hidden or cut-off marker would give a biased centre, and a blob of the right hue but the wrong
        size, shape or colour strength (dark clothes, a poster, a reflection) is not a marker: both are reported
        as missing instead. A marker whose outline was fitted (``Measurement.outlined``) has shown its size and shape
        edge by edge; the blob's area, noisier in a compressed stream, is then not needed. The colour strength (the
        marker's level in its plane) may follow the light within ``level_range`` of the configured colour, and from
        frame to frame within a factor of two. A blob smaller than the learned area and more lopsided than the
        rover's whole marker is (:meth:`lopsided_limit`) has a part hidden, however near the band's middle.
        """
        if m.at_image_edge:
            return False
        low_level, high_level = config.level_range
        if nominal_level > 0 and not low_level <= m.level / nominal_level <= high_level:
            return False
        if self.level > 0 and not 0.5 <= m.level / self.level <= 2.0:
            return False
        if m.outlined:
            return True  # its four edges were found where a whole marker of its size has them
        ratio = m.area_cm2 / expected_area_cm2
        low, high = (
            self.area_band(expected_area_cm2, config.min_area_fraction, config.max_area_fraction)
            if learned
            else config.acquire_area_range
        )
        if learned:
            self.measured(frame, m.area_cm2, m.xy_cm)
        steady = learned and ratio < low and self.steady_below(ratio, expected_area_cm2, config, frame)
        below = learned and ratio < low and not steady and self.config.front_color_bgr is None  # (two-tone: no)
        stretch = wear_stretch(cm_per_px, m.axis_rad) if below and cm_per_px is not None else 1.0
        step = self.step_cm(m, frame) if below else None
        nominal = config.marker_area_cm2
        symmetric = below and (
            symmetric_below(m, ratio, _aspect(config), step, stretch)
            or nominal_below(m, m.area_cm2 / nominal, expected_area_cm2 / nominal, step)
        )
        relearn = False
        whole = low <= ratio <= high or steady or symmetric
        if not whole and not (learned and self.core_whole(m, ratio, config)):
            if not (learned and self.relearn(m, config, frame)):
                return False
            relearn = True
        if m.elongation > _aspect(config) * config.max_elongation_factor or self.core_joined(m, frame):
            return False
        # a two-tone marker's coloured part is another shape; a whole blob's asymmetry is learned every few frames
        smaller = learned and ratio < LOPSIDED_RATIO
        unchecked = self.filter is None  # being acquired: no prediction to check the blob against
        weights = m.weights if self.config.front_color_bgr is None else None
        wanted = smaller or unchecked or (learned and frame % SKEW_EVERY == 0)
        skew = point_asymmetry(weights) if weights is not None and wanted else None
        px = float(np.maximum(weights, 0.0).sum()) if weights is not None and skew is not None else SKEW_PX
        if skew is not None and (smaller or unchecked) and skew > self.lopsided_limit(px):
            return False  # smaller than the rover's own marker, or found with nothing to check it by, and lopsided
        if ratio > JOINED_RATIO and weights is not None and self._joined(m, skew):
            return False  # larger, lopsided and pulled off: joined to something of its hue
        if relearn:
            self.relearned_at = frame  # its areas are forgotten once it is taken (Pipeline)
        elif skew is not None and learned and ratio >= LOPSIDED_RATIO:
            self.skews.append(skew * math.sqrt(max(px, 1.0) / SKEW_PX))
        return True

    def lopsided_limit(self, px: float = SKEW_PX) -> float:
        """How lopsided (``edge.blob_shape.point_asymmetry``) a blob of ``px`` pixels (its coverage's sum; by
        default the reference :data:`SKEW_PX`) below :data:`LOPSIDED_RATIO` of the learned area may be and still be
        the whole marker: twice the median of this rover's whole blobs, plus 0.1, at least :data:`LOPSIDED_FLOOR`;
        :data:`LOPSIDED_UNKNOWN` before ten are known.

        The area band alone lets a marker that a leg or a box hides a little more each frame through: each frame's
        area is within the band's scatter of the last, the filter follows the centre toward the part left (2.5 cm
        off in the family's occlusion clip with seed 3117). A hidden corner makes the blob lopsided (7 % of the
        marker: 0.34, at any size). A stream's grain makes a whole marker lopsided too, more where it spans fewer
        pixels: over a clip on wood (cross 14641, 4:2:0 q78) the median fell from 0.13-0.16 at 150-250 pixels to
        0.04-0.07 at 700 or more, about as the inverse square root of the pixels. Each whole blob's asymmetry is
        learned scaled by that root to :data:`SKEW_PX` pixels (every third frame's, :data:`SKEW_EVERY`; 20 us), and
        the median scaled back to ``px``: learned near the camera, a rover's limit on the far side was 0.3 where its
        whole marker showed 0.35-0.5, refused for 10-20 frames running (that clip's green rover). Ten seconds count,
        so a part hidden a little more each second does not draw the limit up (docs/benchmarks.md, "A marker hidden
        a little more each frame")."""
        if len(self.skews) < 10:
            return LOPSIDED_UNKNOWN
        scale = math.sqrt(SKEW_PX / px) if px > 0.0 else 1.0
        return max(LOPSIDED_FLOOR, 2.0 * float(statistics.median(self.skews)) * scale + 0.1)

    def _joined(self, m: Measurement, skew: float | None = None) -> bool:
        """Is a blob larger than the marker the marker joined to something of its hue? Lopsided, and its centre pulled
        farther from the prediction than a compressed stream moves a whole one (a far-side marker in a 4:2:0 q60
        stream: lopsided up to 0.4 at times, 1 cm off; the blue marker joined to a shaded body: 0.6-0.9, 3-4 cm).
        ``skew``: the blob's point asymmetry when :meth:`whole_marker` measured it this frame."""
        if m.weights is None or (point_asymmetry(m.weights) if skew is None else skew) <= JOINED_SKEW:
            return False
        step = self.innovation_cm(m)
        return step is None or step > JOINED_STEP_CM

    def innovation_cm(self, m: Measurement) -> float | None:
        """How far the measurement's centre (with the centre correction last applied) lies from where the rover's
        filter expects it this frame, when its row was exposed; None while it has no filter (lost, being acquired)."""
        if self.filter is None:
            return None
        x, y = self.filter.position
        vx, vy = self.filter.velocity or (0.0, 0.0)
        dt = self.row_delay_s(m) if self.filter.on_frame_time else 0.0  # before: the estimate is at the rows' time
        return math.hypot(m.xy_cm[0] + self.offset_cm[0] - x - vx * dt, m.xy_cm[1] + self.offset_cm[1] - y - vy * dt)

    def step_cm(self, m: Measurement, frame: int) -> float | None:
        """How far the measurement's centre lies from where the rover is expected: the filter's innovation
        (:meth:`innovation_cm`) while it has one; lost (in the last :data:`SEEN_FRAMES` frames), the distance from
        where it was last seen. A parked rover whose worn marker was refused a few frames running (turning on the
        spot at the far side of a coarse 4:2:0 stream) is lost with its filter; found again where it stood, its centre
        is as well placed as the filter's prediction would have put it. One that drove on is farther than any step a
        worn marker is taken within, and is found as any lost rover is. None: never seen, or lost longer."""
        if self.filter is not None:
            return self.innovation_cm(m)
        if self.seen is None or self.lost_at is None or frame - self.lost_at > SEEN_FRAMES:
            return None
        x, y, _ = self.seen
        return math.hypot(m.xy_cm[0] + self.offset_cm[0] - x, m.xy_cm[1] + self.offset_cm[1] - y)

    def row_delay_s(self, m: Measurement) -> float:
        """How long after the frame's time (its first row's exposure) the marker's row was exposed under a rolling
        shutter (``line_time_s``); 0 without."""
        return max(m.uv_px[1], 0.0) * self.line_time_s

    def at_frame_time(self, obs: Observation) -> Observation:
        """``obs`` at the frame's time: under a rolling shutter a marker lower in the frame was exposed later, where
        the rover had moved on (along its filter's velocity; as measured while it has none)."""
        delay = self.row_delay_s(obs.measurement)
        if delay == 0.0 or self.filter is None:
            return obs
        m = obs.measurement
        xy, r = self.filter.back_to_frame_time(m.xy_cm, obs.r_cm2, delay)
        return Observation(replace(m, xy_cm=xy), r, (m.xy_cm[0] - xy[0], m.xy_cm[1] - xy[1]))

    def steady_below(self, ratio: float, expected_cm2: float, config: TrackerSettings, frame: int) -> bool:
        """Is a blob showing less than the area band's share (``ratio`` of the learned area) a whole marker all the
        same?

        In a stream that scatters a whole marker's area from frame to frame (4:2:0 chroma at low JPEG quality moves
        its boundary's coverage), the area also settles at other levels for a while, below the learned one by a few
        of those scatters. A marker a leg hides a little more each frame does not stay level; one hidden at once
        steps down first. A blob is taken when the last frames' areas are level (:meth:`steady`) and it is within
        :data:`STEADY_SCATTERS` of the rover's own scatters below its learned area; where the stream scatters the
        area little (a clean camera) that is no wider than the band, and a partly hidden marker stays refused.
        """
        low, _ = self.area_band(expected_cm2, config.min_area_fraction, config.max_area_fraction, STEADY_SCATTERS)
        return ratio >= low and self.steady(frame, expected_cm2)

    def relearn(self, m: Measurement, config: TrackerSettings, frame: int) -> bool:
        """Should a blob outside the area band make this rover forget its learned area and start learning afresh?

        A learned area can be wrong: measurements that grew a little at a time (a wrong light on the marker made it
        look a fifth larger, frame after frame) take it along, and from then on the real marker is refused, for
        good, since refused areas are never learned. When the rover has been lost for :data:`RELEARN_FRAMES` and a
        blob within the span areas are first learned from (:data:`LEARN_SPAN` of the nominal area) is nearer the
        nominal area than the learned area is, by :data:`RELEARN_NEARER` at least, has the marker's shape (its
        elongation within :data:`RELEARN_SHAPE` of the configured aspect) and has stayed level (:meth:`steady`)
        as one blob (:meth:`one_blob`), the configuration is believed: the blob is the marker and the learned area
        the mistake. A marker partly hidden is farther from the nominal area than a plausible learned area; where
        the real marker is off the configured size, so that a hidden part could bring it nearer, the hidden end
        changes its shape (15 % of its length hidden: elongation 1.28 -> 1.09)."""
        if self.lost_at is None or frame - self.lost_at < RELEARN_FRAMES:
            return False
        nominal = config.marker_area_cm2
        expected = self.expected_area(nominal)
        lo, hi = LEARN_SPAN
        if not lo <= m.area_cm2 / nominal <= hi or abs(m.elongation / _aspect(config) - 1.0) > RELEARN_SHAPE:
            return False
        nearer = abs(math.log(expected / nominal)) - abs(math.log(m.area_cm2 / nominal))
        return nearer >= math.log(RELEARN_NEARER) and self.steady(frame, expected) and self.one_blob(RELEARN_STEP_CM)

    def estimate(self, obs: Observation, theta_rad: float | None, quality: float) -> RoverEstimate:
        """This frame's estimate: the filtered pose and velocity, and the measurement ``obs`` they took in (for a
        fusion of several cameras, which filters the measurements once, not the filters' outputs)."""
        assert self.filter is not None
        x_cm, y_cm = self.filter.position
        vx_cm_s, vy_cm_s = self.filter.velocity or (None, None)
        r = obs.r_cm2
        return RoverEstimate(
            rover_id=self.config.id,
            x_cm=x_cm,
            y_cm=y_cm,
            theta_rad=theta_rad,
            vx_cm_s=vx_cm_s,
            vy_cm_s=vy_cm_s,
            quality=quality,
            uv_px=obs.measurement.uv_px,
            box_px=self.box,
            measured_xy_cm=obs.measurement.xy_cm,
            measured_cov_cm2=(float(r[0, 0]), float(r[0, 1]), float(r[1, 1])),
        )

    def within_reach(self, xy_cm: tuple[float, float], t_s: float, max_speed_cm_s: float, slack_cm: float) -> bool:
        """Could the rover be at ``xy_cm`` at ``t_s``, driving at most ``max_speed_cm_s`` since it was last seen
        (``slack_cm`` more)? Always, before it has been seen at all."""
        if self.seen is None:
            return True
        x, y, t = self.seen
        return math.hypot(xy_cm[0] - x, xy_cm[1] - y) <= max_speed_cm_s * max(0.0, t_s - t) + slack_cm


def _aspect(config: TrackerSettings) -> float:
    """The marker's length over its width (at least 1)."""
    return max(config.marker_length_cm, config.marker_width_cm) / min(config.marker_length_cm, config.marker_width_cm)
