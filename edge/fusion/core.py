"""The fusion core: every board's detections in, one pose per rover per frame of the shared clock out (pure).

* **Time**: each detection's capture time is moved onto the reference clock with its board's estimated offset
  (:mod:`edge.fusion.clock`). Live, a detection older than ``max_age_s`` on the fuser's clock when it arrives is
  dropped (a bridge that comes back with queued messages replays nothing stale).
* **Association**: by id (each board's tracker knows the rovers by their markers), checked by position: a detection
  whose normalised innovation against the rover's filter exceeds ``gate_nis`` is refused (a board that mistook one
  rover for another cannot drag the fused track); if only refused detections arrive for ``reacquire_s`` the rover
  is re-initialised where they say it is (it really moved: there is no other evidence), unless another rover's
  live track is there (``claim_radius_cm``): then the board took that rover for this one. A track of one
  measurement is a guess and gives no pose; another board's detection a rover's width from it replaces it at once
  (the first board to speak at the start may have taken another rover for this one). Each board's
  covariances are scaled by the robust level of its innovations (:meth:`BoardState.saw_nis`): a board more wrong
  than its model says is trusted less, not refused.
* **One filter per rover** (:class:`edge.fusion.track.CvState`, constant velocity, the detections' covariances as
  measurement noise) for as long as any board sees it: overlaps are fused by uncertainty, and a
  rover passing from one view to the next keeps its filter, its id and its estimate. Each board's covariance grows
  near the edge of its view, so the weight moves from one board to the next over a few centimetres of travel.
* **Order**: detections are fused in the order of their (corrected) capture times. One that arrives up to
  ``late_direct_s`` late (another board's frame of the same period) is moved to the filter's time along the
  estimated velocity, its covariance grown by the velocity's uncertainty over the gap; a later one (a slower board)
  is put in its place and the last ``replay_s`` are filtered again.
* **Output**: the first detection of a rover in frame ``k`` of the shared clock (``k = round(t * fps)``) gives that
  rover's pose for frame ``k`` (live, one half a frame newer than the last that rounds onto its frame gives the next:
  the clocks' corrections move captures near a half-frame across it). Live (``pose_time = "measured"``) the pose is
  the filter's state at its newest measurement's capture instant (on the fuser's clock, to the millisecond below):
  never dated later than anything measured, so ``arrival - t`` is a true grab-to-pose latency and a rover's idea of
  its pose's age is right; for a recording (``"frame"``) the state is moved to ``k / fps``. The published pose is the
  filter's, except around a handover: for ``handover_s`` after the set of boards measuring a rover changes, the pose
  moves along the filter's velocity smoothed over ``shown_velocity_s`` (the kick a correction gives the filter's
  velocity is not shown at once), plus at most ``max_correction_cm`` a frame towards the filter, so a better board
  joining or a worse one leaving moves the rover smoothly and the controllers see no step; what is left of that
  difference when the handover ends shrinks by ``max_correction_cm`` a frame. Elsewhere a rover that turns or brakes
  is shown where the filter has it (smoothing every frame held it 10-15 cm behind). A rover not measured for
  ``timeout_s`` is missing: no pose is published for it (the rovers' own staleness stops them).
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from edge.fusion.clock import ClockAligner, ClockSettings, OffsetEstimate
from edge.fusion.detections import Detection, Detections
from edge.fusion.track import CvState

FloatArray = NDArray[np.float64]
NOISE_WINDOW = 256
HALF_FRAME_SLACK_S = 0.002  # a live capture this near the next frame's rounding is that frame's ("Output")
NOISE_MIN_SAMPLES = 64
CHI2_2_MEDIAN = 1.386
MAX_NOISE_SCALE = 25.0


@dataclass(frozen=True)
class FusionSettings:
    """Tuning of :class:`Fuser` (units in the names)."""

    fps: float = 30.0  # the shared clock's frame rate
    max_age_s: float = 0.25  # live: a detection older than this when it arrives is stale
    timeout_s: float = 0.5  # a rover not measured for this long is missing
    board_timeout_s: float = 1.0  # a board silent this long is missing, its view reported
    gate_nis: float = 25.0  # chi-square, 2 dof: about 5 sigma
    reacquire_s: float = 0.3
    replay_s: float = 0.2
    accel_sigma_cm_s2: float = 20.0  # smoother than one camera's filter: several boards' seams meet in it
    # no fading step (the single camera's filter has one for manoeuvres): with several boards an innovation that
    # large is mostly one board's outlier, and fading would give it the gain; the process noise follows the turns
    fade_nis: float = math.inf
    heading_s: float = 0.2  # a board's heading is used this long
    heading_min_speed_cm_s: float = 5.0
    clock: ClockSettings = field(default_factory=ClockSettings)

    late_direct_s: float = 0.035  # about one frame
    claim_radius_cm: float = 20.0  # two markers' centres are never closer: a body is 20 cm wide
    initial_speed_sigma_cm_s: float = 50.0
    max_correction_cm: float = 0.25  # per frame beyond the shown motion: a handover moves a rover smoothly
    handover_s: float = 1.0  # how long after the boards measuring a rover change its pose is smoothed
    shown_velocity_s: float = 0.15  # the shown motion's velocity: the filter's, smoothed over this time
    shown_warmup_s: float = 0.5  # a new track shows the filter's velocity as it is for this long
    # "measured": a pose is the state at its newest measurement's capture instant (live: never dated after what was
    # measured, so a rover's pose age is true); "frame": at the shared clock's frame instant (a recording's series)
    pose_time: Literal["measured", "frame"] = "measured"


@dataclass(frozen=True)
class FusedPose:
    """One rover's fused state for frame ``tick`` of the shared clock (``tick = round(t_s * fps)``), at ``t_s`` on
    the reference clock (:attr:`FusionSettings.pose_time`).
    ``boards``: the boards whose detections the filter took in this frame's period."""

    rover_id: str
    tick: int
    t_s: float
    x_cm: float
    y_cm: float
    theta_rad: float | None
    vx_cm_s: float | None
    vy_cm_s: float | None
    quality: float
    boards: tuple[str, ...]


class _Measurement(NamedTuple):  # immutable like a frozen dataclass, built in a third of its time
    t_s: float  # reference clock
    x: float
    y: float
    rxx: float
    rxy: float
    ryy: float
    board: str


@dataclass
class _Track:
    """One rover: its filter (at ``t_s``), the last ``replay_s`` of measurements, each with the filter's state and
    time after it (a snapshot: no second filter re-stepped behind), and the state before them (``checkpoint``)."""

    filter: CvState
    t_s: float
    checkpoint: tuple[float, ...]  # CvState.snapshot()
    checkpoint_t_s: float
    log: deque[tuple[_Measurement, tuple[float, ...], float]] = field(default_factory=deque)
    last_tick: int = -1
    # the last published (t, x, y) and the velocity it moved along: corrections are spread from it
    shown: tuple[float, float, float, float, float] | None = None
    shown_boards: tuple[str, ...] = ()  # the boards that measured the rover for the last published pose
    handover_until_s: float = -math.inf  # the pose is smoothed until then (a handover)
    offset: tuple[float, float] = (0.0, 0.0)  # shown minus the filter's estimate at the last published pose
    born_s: float = -math.inf
    last_measured_s: float = -math.inf
    refused_since_s: float | None = None
    theta_rad: float | None = None
    theta_t_s: float = -math.inf
    boards_now: dict[str, float] = field(default_factory=dict)  # board -> last time it measured this rover


@dataclass
class BoardState:
    """What the fuser knows of one board."""

    edge_id: str
    frames: int = 0
    last_arrival_s: float | None = None  # the fuser's clock (live)
    last_capture_s: float | None = None  # reference clock
    stale: int = 0
    refused: int = 0
    late: int = 0
    view_cm: tuple[tuple[float, float], ...] = ()
    online: bool = True  # False once its retained status says offline
    rovers: set[str] = field(default_factory=set)
    noise_scale: float = 1.0  # how much larger its errors are than its covariances say (>= 1)
    _nis: deque[float] = field(default_factory=lambda: deque(maxlen=NOISE_WINDOW))
    _nis_count: int = 0

    def saw_nis(self, nis: float) -> None:
        """Track the board's normalised innovations; its covariances are scaled by their robust level.

        The median of a 2-dof chi-square is 1.386: a board whose detections are as good as their covariances say
        keeps the scale at 1; an overconfident one (crowded markers, a worse view than its model knows) gets its
        covariances widened, neither refused nor trusted too much. A median ignores the wrong rover's few detections."""
        self._nis.append(min(nis, 1e6))
        self._nis_count += 1
        if len(self._nis) >= NOISE_MIN_SAMPLES and self._nis_count % 32 == 0:
            level = statistics.median(self._nis) / CHI2_2_MEDIAN  # np.median of a deque: 10x the time
            self.noise_scale = min(max(level * self.noise_scale, 1.0), MAX_NOISE_SCALE)


@dataclass(frozen=True)
class FusionStatus:
    """The fuser's view of the system at one instant."""

    boards: tuple[BoardState, ...]
    offsets: dict[str, OffsetEstimate]
    rovers: tuple[str, ...]  # measured within timeout_s
    missing: tuple[str, ...]  # seen before, not within timeout_s
    missing_boards: tuple[str, ...]  # offline or silent for board_timeout_s
    missing_views: tuple[tuple[tuple[float, float], ...], ...]  # their views: the areas nobody watches now


class Fuser:
    """Fuses the detections of every board into one pose per rover per shared-clock frame.

    ``reference``: the board whose clock is the reference (offline: the first file); None live (the fuser's own
    clock, through arrival times). ``aligner``: an already-trained :class:`ClockAligner` (offline, estimated over
    the whole recording first); by default one of its own, learning as detections arrive.
    """

    def __init__(
        self,
        settings: FusionSettings = FusionSettings(),
        reference: str | None = None,
        aligner: ClockAligner | None = None,
        learn_offsets: bool = True,
    ) -> None:
        self.settings = settings
        self.aligner = aligner if aligner is not None else ClockAligner(settings.clock, reference)
        self.learn_offsets = learn_offsets
        self.boards: dict[str, BoardState] = {}
        self.tracks: dict[str, _Track] = {}
        self._latest_s = -math.inf
        self.unlearned: list[Detections] = []  # fused, not yet given to the clock aligner

    # -- input ------------------------------------------------------------------------------------------------------
    def add(self, d: Detections, now_s: float | None = None, learn: bool = True) -> list[FusedPose]:
        """Fuse one board's frame; returns the poses due now. ``now_s``: the fuser's clock at arrival (live).

        ``learn=False``: the frame's evidence on the clocks is kept for :meth:`learn_pending` (live, after the
        poses are out: a third of the work, none of which the poses of this frame need)."""
        board = self.boards.get(d.edge_id)
        if board is None:
            board = self.boards[d.edge_id] = BoardState(d.edge_id)
        board.view_cm = d.view_cm
        if now_s is not None:
            board.last_arrival_s = now_s
            board.online = True
            if self.learn_offsets:
                self.aligner.observe_arrival(d.edge_id, d.t_sent_s, now_s)
        offset = self.aligner.offset_s(d.edge_id)
        t_ref = d.t_capture_s - offset
        if now_s is not None and now_s - t_ref > self.settings.max_age_s:
            board.stale += 1
            return []
        if self.learn_offsets:
            self.unlearned.append(d)
        board.frames += 1
        board.last_capture_s = t_ref if board.last_capture_s is None else max(board.last_capture_s, t_ref)
        board.rovers = {r.rover_id for r in d.rovers}
        self._latest_s = max(self._latest_s, t_ref)
        out = []
        for r in d.rovers:
            pose = self._fuse(r, d.edge_id, t_ref, board)
            if pose is not None:
                out.append(pose)
        if learn:
            self.learn_pending()
        return out

    def learn_pending(self) -> None:
        """Give the clock aligner the frames fused since it last learned."""
        for d in self.unlearned:
            self.aligner.observe(d)
        self.unlearned.clear()

    def board_offline(self, edge_id: str) -> None:
        """The board's retained status says it is offline (its last will): its view is reported missing at once."""
        board = self.boards.get(edge_id)
        if board is None:
            board = self.boards[edge_id] = BoardState(edge_id)
        board.online = False

    # -- one detection ----------------------------------------------------------------------------------------------
    def _fuse(self, r: Detection, edge_id: str, t_s: float, board: BoardState) -> FusedPose | None:
        s = self.settings
        xx, xy, yy = r.cov_cm2
        k = board.noise_scale
        m = _Measurement(t_s, float(r.xy_cm[0]), float(r.xy_cm[1]), k * xx, k * xy, k * yy, edge_id)
        track = self.tracks.get(r.rover_id)
        if track is None or t_s - track.last_measured_s > s.timeout_s:
            if self._claimed(r.rover_id, m):
                board.refused += 1  # where another rover is: this board took that rover for this one
                return None
            track = self._start(r.rover_id, m)
        elif t_s < track.checkpoint_t_s:
            board.late += 1  # older than everything kept for replay: its moment has passed
            return None
        elif not self._inside_gate(track, m, board):
            board.refused += 1
            if track.refused_since_s is None:
                track.refused_since_s = t_s
            # a track of one measurement is a guess: a board may have taken another rover for this one at the
            # start. A second board's word a rover's width away replaces it at once; an established track waits
            f = track.filter
            guess = f.updates < 2 and math.hypot(f.x - m.x, f.y - m.y) > s.claim_radius_cm
            if (not guess and t_s - track.refused_since_s < s.reacquire_s) or self._claimed(r.rover_id, m):
                return None
            track = self._start(r.rover_id, m)  # only refused detections for a while: the rover is there
        else:
            track.refused_since_s = None
            self._apply(track, m)
        track.last_measured_s = max(track.last_measured_s, t_s)
        track.boards_now[edge_id] = t_s
        if r.theta_rad is not None and t_s >= track.theta_t_s:
            track.theta_rad, track.theta_t_s = r.theta_rad, t_s
        if track.filter.updates < 2:
            return None  # no pose from one measurement: it is published once a second one agrees
        if s.pose_time == "frame":
            tick = round(t_s * s.fps)
            t_pose = tick / s.fps
        else:  # the newest capture instant, to the wire's millisecond and never later
            t_pose = math.floor(track.t_s * 1e3 + 1e-6) / 1e3
            tick = round(t_pose * s.fps)
        newer = s.pose_time == "measured" and track.shown is not None and t_pose - track.shown[0] >= 0.5 / s.fps
        late = t_pose * s.fps - track.last_tick >= 0.5 - HALF_FRAME_SLACK_S * s.fps  # at the next frame's rounding
        if tick <= track.last_tick and not (newer and late):  # half a frame newer, at the next: the next ("Output")
            return None  # this frame's pose is out; the detection is in the filter for the next one
        track.last_tick = tick = max(tick, track.last_tick + 1)
        return self._pose(r.rover_id, track, tick, t_pose, r.quality)

    def _start(self, rover_id: str, m: _Measurement) -> _Track:
        f = CvState.start(m.x, m.y, m.rxx, m.rxy, m.ryy, self.settings.initial_speed_sigma_cm_s)
        track = _Track(filter=f, t_s=m.t_s, checkpoint=f.snapshot(), checkpoint_t_s=m.t_s, born_s=m.t_s)
        old = self.tracks.get(rover_id)
        if old is not None:
            track.last_tick = old.last_tick
        self.tracks[rover_id] = track
        return track

    def _inside_gate(self, track: _Track, m: _Measurement, board: BoardState) -> bool:
        f, dt = track.filter, m.t_s - track.t_s
        # the filter's covariance grows between its time and the measurement's (either way) by the acceleration
        grow = (self.settings.accel_sigma_cm_s2 * dt * dt / 2.0) ** 2 + (f.puu + f.pvv) / 2.0 * dt * dt
        nis = f.nis(m.x, m.y, m.rxx + grow, m.rxy, m.ryy + grow, dt if f.updates >= 2 else 0.0)
        if f.updates >= 3:
            board.saw_nis(nis)
        return nis <= self.settings.gate_nis

    def _claimed(self, rover_id: str, m: _Measurement) -> bool:
        """A live track of another rover is within a marker's reach of ``m``: the detection is that rover's."""
        reach = self.settings.claim_radius_cm
        for other_id, other in self.tracks.items():
            if other_id == rover_id or m.t_s - other.last_measured_s > self.settings.timeout_s:
                continue
            f, dt = other.filter, m.t_s - other.t_s
            if math.hypot(f.x + f.vx * dt - m.x, f.y + f.vy * dt - m.y) < reach:
                return True
        return False

    def _apply(self, track: _Track, m: _Measurement) -> None:
        s = self.settings
        late = track.t_s - m.t_s
        f = track.filter
        if late <= 0.0:
            self._step(f, track.t_s, m)
            track.t_s = m.t_s
            track.log.append((m, f.snapshot(), m.t_s))
        elif late <= s.late_direct_s:  # another board's frame of the same period: brought forward, no replay
            grow = (f.puu + f.pvv) / 2.0 * late * late
            f.update(m.x + f.vx * late, m.y + f.vy * late, m.rxx + grow, m.rxy, m.ryy + grow, s.fade_nis)
            track.log.append((m, f.snapshot(), track.t_s))
        else:  # late: put it in its place and filter the kept measurements again from the state before them
            entries = sorted([*(e for e, _, _ in track.log), m], key=lambda e: e.t_s)
            f, t, track.log = CvState.restore(track.checkpoint), track.checkpoint_t_s, deque()
            for e in entries:
                self._step(f, t, e)
                t = max(t, e.t_s)
                track.log.append((e, f.snapshot(), t))
            track.filter, track.t_s = f, t
        # what leaves the replay window is in the state after it (kept in order: the log is the order applied)
        horizon = track.t_s - s.replay_s
        while len(track.log) > 1 and track.log[0][0].t_s < horizon:
            _, track.checkpoint, track.checkpoint_t_s = track.log.popleft()

    def _step(self, f: CvState, t_s: float, m: _Measurement) -> None:
        """Predict ``f`` from ``t_s`` to the measurement's time (if later) and fuse it."""
        if m.t_s > t_s:
            f.predict(m.t_s - t_s, self.settings.accel_sigma_cm_s2)
        f.update(m.x, m.y, m.rxx, m.rxy, m.ryy, self.settings.fade_nis)

    def _pose(self, rover_id: str, track: _Track, tick: int, t_pose: float, quality: float) -> FusedPose:
        s = self.settings
        f = track.filter
        vel = f.velocity
        x, y = f.x, f.y
        if vel is not None:
            x += vel[0] * (t_pose - track.t_s)
            y += vel[1] * (t_pose - track.t_s)
        shown_v = vel
        recent = tuple(sorted(b for b, t in track.boards_now.items() if track.t_s - t <= 1.5 / s.fps))
        if track.shown is not None and vel is not None and 0.0 < t_pose - track.shown[0] <= 3.5 / s.fps:
            st, sx, sy, ux, uy = track.shown
            dt = t_pose - st
            if recent != track.shown_boards:
                track.handover_until_s = t_pose + s.handover_s
            limit = s.max_correction_cm * dt * s.fps
            if t_pose <= track.handover_until_s:
                # a handover (a better board joins, a worse one leaves): the correction is spread over frames, the
                # shown pose moving along the filter's velocity smoothed over shown_velocity_s plus at most
                # max_correction_cm a frame
                vx, vy = vel
                if t_pose - track.born_s > s.shown_warmup_s:
                    a = dt / (s.shown_velocity_s + dt)
                    vx, vy = ux + a * (vx - ux), uy + a * (vy - uy)
                shown_v = (vx, vy)
                px, py = sx + vx * dt, sy + vy * dt
                dx, dy = x - px, y - py
                step = math.hypot(dx, dy)
                if step > limit:
                    px, py = px + dx * limit / step, py + dy * limit / step
                else:
                    px, py = x, y
                track.offset = (px - x, py - y)
                x, y = px, py
            else:
                # no handover: the filter's estimate as it is, plus what is left of the last handover's
                # difference, shrinking by max_correction_cm a frame
                ox, oy = track.offset
                left = math.hypot(ox, oy)
                if left > limit:
                    track.offset = (ox - ox * limit / left, oy - oy * limit / left)
                    x, y = x + track.offset[0], y + track.offset[1]
                else:
                    track.offset = (0.0, 0.0)
        else:
            track.offset = (0.0, 0.0)  # a new track or one back after a gap: shown where the filter has it
        track.shown_boards = recent
        track.shown = None if shown_v is None else (t_pose, x, y, shown_v[0], shown_v[1])
        theta = track.theta_rad if track.t_s - track.theta_t_s <= s.heading_s else None
        clear = f.clear_velocity() if theta is None else None  # a standing rover's velocity has no direction
        if clear is not None and math.hypot(*clear) >= s.heading_min_speed_cm_s:
            theta = math.atan2(clear[1], clear[0])
        return FusedPose(
            rover_id=rover_id,
            tick=tick,
            t_s=t_pose,
            x_cm=x,
            y_cm=y,
            theta_rad=theta,
            vx_cm_s=None if shown_v is None else shown_v[0],
            vy_cm_s=None if shown_v is None else shown_v[1],
            quality=quality,
            boards=recent,
        )

    # -- state ------------------------------------------------------------------------------------------------------
    def status(self, now_s: float | None = None) -> FusionStatus:
        """Boards, offsets, rovers and what is missing at ``now_s`` (the fuser's clock; offline: the newest data)."""
        s = self.settings
        now = self._latest_s if now_s is None else now_s
        seen = tuple(sorted(r for r, t in self.tracks.items() if now - t.last_measured_s <= s.timeout_s))
        missing = tuple(sorted(r for r in self.tracks if r not in seen))
        silent = []
        for b in self.boards.values():
            last = b.last_arrival_s if now_s is not None else b.last_capture_s
            if not b.online or last is None or now - last > s.board_timeout_s:
                silent.append(b)
        return FusionStatus(
            boards=tuple(self.boards.values()),
            offsets=self.aligner.estimates(),
            rovers=seen,
            missing=missing,
            missing_boards=tuple(b.edge_id for b in silent),
            missing_views=tuple(b.view_cm for b in silent if b.view_cm),
        )
