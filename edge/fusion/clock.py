"""The boards' clock offsets, estimated from the data: never trusted from the boards themselves.

Each board stamps its frames with its own clock; boards synchronised by NTP still differ by a few milliseconds,
and a rover at 30 cm/s moves 0.3 cm in 10 ms, as much as the whole measurement error. A board's offset is its
clock minus the reference clock (the fuser's own clock live; the first board's offline).

Two sources, combined by weighted least squares over all boards (:meth:`ClockAligner.solve`):

* **rovers seen by two boards** (the overlaps): each board's sample of a rover is compared with the other board's
  track of it, interpolated at the instant the estimates in use say is the same. The difference is
  ``e = seam + v * (d - d_used)``: the two calibrations' disagreement there (``seam``, a few millimetres) plus the
  rover's velocity times the error of the relative offset ``d = off_b - off_a``. Each pair of boards keeps the
  weighted normal equations of ``(seam, d)`` (weights: the detections' covariances), so a rover seen at rest or
  moving in different directions separates the two; a prior of ``seam_sigma_cm`` on the seam keeps the system
  solvable, and where every rover crossed one way at one speed the offset's variance says it is unknown. Old
  evidence fades with ``memory_s``, so a slowly drifting clock is followed.
* **arrival times** (live only): ``ts`` (the board's clock when it sent) minus the arrival time on the fuser's
  clock is ``off_b - latency``; its running maximum is the offset less the smallest network latency (about 0.2 ms
  on a LAN). It anchors every board to the fuser's clock, and is the only source for a board without overlap. A
  delayed message (a bridge that queued it through an outage) only lowers that difference, so it never moves the
  maximum; the maximum itself falls no faster than a clock can drift (``drift_rate``), so a board whose clock is
  stepped back is followed at that pace (5 ms in 10 s). It is also a hard floor: a board's offset is never
  estimated below it (:func:`_at_least_the_arrival_bound`), so no capture is dated after its own arrival.

Without the seam term, a 3 mm disagreement crossed one way at 25 cm/s reads as a 12 ms offset.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from edge.fusion.detections import Detections

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ClockSettings:
    """Tuning of :class:`ClockAligner` (units in the names)."""

    max_gap_s: float = 0.1  # board b's two samples around the instant must be this close
    max_residual_cm: float = 5.0  # larger residuals are an association mistake, not a clock
    velocity_window_s: float = 0.2  # a rover's velocity is fitted over this much of a board's track
    compare_every_s: float = 0.5  # each rover's track is compared this often per board (the evidence is ample)
    seam_sigma_cm: float = 1.0  # prior: two boards' calibrations agree to about this in their overlap
    memory_s: float = 60.0  # time constant of forgetting old evidence
    history_s: float = 1.0  # how much of each board's track of each rover is kept for interpolation
    drift_rate: float = 5e-4  # how fast the arrival bound may fall: NTP slews a clock by at most 500 ppm
    arrival_sigma_s: float = 0.002  # how well the arrival bound pins a board to the fuser's clock
    prior_sigma_s: float = 1.0  # a board with no evidence at all: offset 0, this unsure
    # live, the offsets are solved again at most this often (data time): a clock moves microseconds in that time,
    # and solving on every message is a third of the fuser's work between a board's frame and its rovers' poses
    solve_every_s: float = 0.1


@dataclass(frozen=True)
class OffsetEstimate:
    """A board's clock offset (its clock minus the reference, s), its 1-sigma, and where it came from."""

    edge_id: str
    offset_s: float
    sigma_s: float
    source: str  # "reference", "overlap", "arrival", "overlap+arrival" or "none"


@dataclass
class _Pair:
    """Evidence on one pair of boards ``(lo, hi)``: the normal equations of ``y = b + v * d`` (weighted least
    squares), ``b`` the pair's calibration disagreement in the overlap (cm), ``d = off_hi - off_lo`` (s)."""

    normal: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    rhs: FloatArray = field(default_factory=lambda: np.zeros(3))
    samples: int = 0
    t_s: float = 0.0  # data time of the last update (for forgetting)

    def estimate(self, seam_sigma_cm: float) -> tuple[float, float] | None:
        """``(d, variance of d)``, with the prior that the calibrations agree to ``seam_sigma_cm``; None when the
        data cannot tell a time offset from a seam (every rover crossed it one way at one speed)."""
        prior = np.diag([1.0 / seam_sigma_cm**2, 1.0 / seam_sigma_cm**2, 0.0])
        try:
            cov = np.linalg.inv(self.normal + prior)
        except np.linalg.LinAlgError:
            return None
        var = float(cov[2, 2])
        if not math.isfinite(var) or var <= 0.0:
            return None
        return float((cov @ self.rhs)[2]), var


@dataclass
class _Sample:
    t_local_s: float
    xy_cm: FloatArray
    var_cm2: FloatArray  # (2, 2)


@dataclass
class _Arrivals:
    """The largest ``ts - arrival`` seen, allowed to fall only as fast as a clock can drift: messages that arrive
    late (a bridge's queue replayed after an outage) never lower it, however long the outage was."""

    bound: float | None = None
    t_s: float = 0.0

    def add(self, value: float, t_arrival_s: float, drift_rate: float) -> None:
        if self.bound is None:
            self.bound = value
        else:
            decayed = self.bound - drift_rate * max(0.0, t_arrival_s - self.t_s)
            self.bound = max(value, decayed)
        self.t_s = t_arrival_s


class ClockAligner:
    """Estimates each board's clock offset from the detections it sends (pure: times come with the data).

    ``reference``: the board whose clock is the reference (offline); None to use the fuser's clock, through the
    arrival times given to :meth:`observe_arrival` (live).
    """

    def __init__(
        self,
        settings: ClockSettings = ClockSettings(),
        reference: str | None = None,
        interpolate_with: dict[str, float] | None = None,
    ) -> None:
        self.settings = settings
        self.reference = reference
        self.interpolate_with = interpolate_with  # offsets to compare tracks at (a second pass), else the estimates
        self._tracks: dict[str, dict[str, deque[_Sample]]] = {}  # rover -> board -> its recent samples
        self._pairs: dict[tuple[str, str], _Pair] = {}  # (a, b), a < b -> evidence on off_b - off_a
        self._compared: dict[tuple[str, str], float] = {}  # (rover, board) -> its last sample compared
        self._arrivals: dict[str, _Arrivals] = {}
        self._boards: list[str] = []
        self._estimates: dict[str, OffsetEstimate] = {}
        self._dirty = True
        self._data_s = -math.inf  # the newest time in the evidence
        self._solved_s = -math.inf  # the data time of the last solve

    # -- evidence ---------------------------------------------------------------------------------------------------
    def observe(self, d: Detections) -> None:
        """Add one board's frame. Each rover's new sample closes an interval of this board's track of it; every
        other board's samples of the rover that fall inside that interval are compared with it, interpolated."""
        self._board(d.edge_id)
        s = self.settings
        fixed = self.interpolate_with
        # held for the whole frame
        offsets = {b: fixed.get(b, 0.0) if fixed is not None else self.offset_s(b) for b in self._boards}
        for r in d.rovers:
            xx, xy, yy = r.cov_cm2
            sample = _Sample(d.t_capture_s, np.array(r.xy_cm), np.array([[xx, xy], [xy, yy]]))
            by_board = self._tracks.setdefault(r.rover_id, {})
            track = by_board.setdefault(d.edge_id, deque())
            key = (r.rover_id, d.edge_id)
            due = sample.t_local_s - self._compared.get(key, -math.inf) >= s.compare_every_s
            if due and track and 0.0 < sample.t_local_s - track[-1].t_local_s <= s.max_gap_s:
                self._compared[key] = sample.t_local_s
                for board, other in by_board.items():
                    if board != d.edge_id and other:
                        self._compare(d.edge_id, track, sample, board, other, offsets)
            track.append(sample)
            while track and track[0].t_local_s < d.t_capture_s - s.history_s:
                track.popleft()

    def observe_arrival(self, edge_id: str, t_sent_board_s: float, t_arrival_s: float) -> None:
        """A message sent at ``t_sent_board_s`` (board clock) arrived at ``t_arrival_s`` (the reference clock)."""
        self._board(edge_id)
        arrivals = self._arrivals.setdefault(edge_id, _Arrivals())
        arrivals.add(t_sent_board_s - t_arrival_s, t_arrival_s, self.settings.drift_rate)
        self._data_s = max(self._data_s, t_arrival_s)
        self._dirty = True

    def _board(self, edge_id: str) -> None:
        if edge_id not in self._boards:
            self._boards.append(edge_id)
            self._dirty = True

    def _compare(
        self, b: str, track: deque[_Sample], p1: _Sample, a: str, others: deque[_Sample], offsets: dict[str, float]
    ) -> None:
        """Board ``a``'s samples inside board ``b``'s interval from its last sample to ``p1``, against ``b``'s track
        interpolated there.

        With ``e = p_a - p_b(tau)``: ``e = seam + v * (d_ab - d_ab_used)``, ``d_ab = off_b - off_a``; the pair's
        normal equations are kept in the orientation of its sorted names. ``v`` is fitted over the last
        ``velocity_window_s`` of ``b``'s track, not taken from the two samples interpolated: a velocity from two
        noisy samples 33 ms apart is off by several cm/s in a random direction, which would look like evidence
        that separates the seam from the clock."""
        s = self.settings
        off_a, off_b = offsets.get(a, 0.0), offsets.get(b, 0.0)
        p0 = track[-1]
        dt = p1.t_local_s - p0.t_local_s
        v = _velocity([q for q in track if q.t_local_s >= p1.t_local_s - s.velocity_window_s] + [p1])
        if v is None:
            return
        sign = 1.0 if a < b else -1.0
        key = (a, b) if a < b else (b, a)
        for sample in others:
            tau = sample.t_local_s - off_a + off_b  # board b's clock at the instant of a's sample, as estimated
            if not p0.t_local_s < tau <= p1.t_local_s:
                continue
            f = (tau - p0.t_local_s) / dt
            e = sample.xy_cm - (p0.xy_cm + f * (p1.xy_cm - p0.xy_cm))
            if float(np.hypot(*e)) > s.max_residual_cm:
                continue  # an association mistake, not a clock
            var = sample.var_cm2 + (1 - f) ** 2 * p0.var_cm2 + f * f * p1.var_cm2
            y = sign * e + v * (sign * (off_b - off_a))  # = seam + v * d, in the pair's orientation
            self._add_pair(key, y, v, np.asarray(np.linalg.inv(var), dtype=np.float64), sample.t_local_s)

    def _add_pair(self, key: tuple[str, str], y: FloatArray, v: FloatArray, w: FloatArray, t_s: float) -> None:
        pair = self._pairs.setdefault(key, _Pair())
        fade = math.exp(-max(0.0, t_s - pair.t_s) / self.settings.memory_s) if pair.samples else 1.0
        design = np.array([[1.0, 0.0, v[0]], [0.0, 1.0, v[1]]])
        pair.normal = pair.normal * fade + design.T @ w @ design
        pair.rhs = pair.rhs * fade + design.T @ w @ y
        pair.samples += 1
        pair.t_s = max(pair.t_s, t_s)
        self._data_s = max(self._data_s, t_s)
        self._dirty = True

    # -- estimates --------------------------------------------------------------------------------------------------
    def offset_s(self, edge_id: str) -> float:
        """The current estimate of the board's offset (0 for a board never seen), solved again when
        ``solve_every_s`` of new evidence is in; never below the board's arrival bound as it is now."""
        if self._dirty and (
            self._data_s - self._solved_s >= self.settings.solve_every_s or edge_id not in self._estimates
        ):
            self.solve()
        est = self._estimates.get(edge_id)
        offset = est.offset_s if est is not None else 0.0
        arrivals = self._arrivals.get(edge_id)
        if arrivals is not None and arrivals.bound is not None:
            offset = max(offset, arrivals.bound)
        return offset

    def estimates(self) -> dict[str, OffsetEstimate]:
        if self._dirty:
            self.solve()
        return dict(self._estimates)

    def pair_samples(self) -> dict[tuple[str, str], int]:
        """How many overlap comparisons back each pair of boards' relative offset."""
        return {k: p.samples for k, p in self._pairs.items()}

    def solve(self) -> dict[str, OffsetEstimate]:
        """Weighted least squares over every board's offset: overlap pairs, arrival bounds, the reference, a prior."""
        s = self.settings
        boards = list(self._boards)
        n = len(boards)
        if n == 0:
            self._estimates, self._dirty = {}, False
            return {}
        index = {b: i for i, b in enumerate(boards)}
        info = np.zeros((n, n))
        rhs = np.zeros(n)
        sources: dict[str, set[str]] = {b: set() for b in boards}
        prior_w = 1.0 / s.prior_sigma_s**2
        info[np.diag_indices(n)] += prior_w
        if self.reference in index:
            i = index[self.reference]
            info[i, i] += 1e12
            sources[self.reference].add("reference")
        for b, arrivals in self._arrivals.items():
            if arrivals.bound is not None and b in index:
                i = index[b]
                bound = arrivals.bound
                w = 1.0 / s.arrival_sigma_s**2
                info[i, i] += w
                rhs[i] += w * bound
                sources[b].add("arrival")
        for (a, b), pair in self._pairs.items():
            found = pair.estimate(s.seam_sigma_cm)
            if found is None or a not in index or b not in index:
                continue
            i, j = index[a], index[b]
            d, var = found  # d = off_b - off_a
            w = 1.0 / var
            info[i, i] += w
            info[j, j] += w
            info[i, j] -= w
            info[j, i] -= w
            rhs[i] -= w * d
            rhs[j] += w * d
            sources[a].add("overlap")
            sources[b].add("overlap")
        cov = np.linalg.inv(info)
        offsets = _at_least_the_arrival_bound(info, rhs, cov @ rhs, self._floors(index))
        out = {}
        for b, i in index.items():
            src = sources[b]
            name = (
                "reference" if "reference" in src else "+".join(x for x in ("overlap", "arrival") if x in src) or "none"
            )
            out[b] = OffsetEstimate(b, float(offsets[i]), float(math.sqrt(max(cov[i, i], 0.0))), name)
        self._estimates, self._dirty, self._solved_s = out, False, self._data_s
        return out

    def _floors(self, index: dict[str, int]) -> dict[int, float]:
        """Each board's least possible offset: ``ts - arrival`` is the offset less a latency, never more."""
        return {index[b]: a.bound for b, a in self._arrivals.items() if a.bound is not None and b in index}


def _at_least_the_arrival_bound(
    info: FloatArray, rhs: FloatArray, offsets: FloatArray, floors: dict[int, float]
) -> FloatArray:
    """The least-squares offsets with each board's offset held at or above its arrival bound.

    A message cannot arrive before it was sent: a board's offset is at least its largest ``ts - arrival``. The
    overlaps may say otherwise (a board whose tracker leads the others' looks like a clock behind), but an
    estimate below the bound would date that board's captures after they reached the fuser. Boards below their
    bound are held at it and the others solved again with them fixed, until none is below (at most one pass per
    board)."""
    held: dict[int, float] = {}
    for _ in range(len(floors)):
        below = {i: f for i, f in floors.items() if i not in held and offsets[i] < f - 1e-9}
        if not below:
            break
        held |= below
        free = np.array([i for i in range(len(rhs)) if i not in held], dtype=np.intp)
        fixed = np.array(sorted(held), dtype=np.intp)
        offsets = offsets.copy()
        offsets[fixed] = [held[i] for i in fixed]
        if free.size:
            a = info[np.ix_(free, free)]
            b = rhs[free] - info[np.ix_(free, fixed)] @ offsets[fixed]
            offsets[free] = np.linalg.solve(a, b)
    return offsets


def _velocity(samples: list[_Sample]) -> FloatArray | None:
    """(2,) cm/s: the least-squares slope of a track's positions over time; None with fewer than 4 samples.
    (Plain floats: numpy's overhead on half a dozen samples was a fifth of the fuser's time.)"""
    n = len(samples)
    if n < 4:
        return None
    t_mean = sum(q.t_local_s for q in samples) / n
    x_mean = sum(float(q.xy_cm[0]) for q in samples) / n
    y_mean = sum(float(q.xy_cm[1]) for q in samples) / n
    denom = sx = sy = 0.0
    for q in samples:
        dt = q.t_local_s - t_mean
        denom += dt * dt
        sx += dt * (float(q.xy_cm[0]) - x_mean)
        sy += dt * (float(q.xy_cm[1]) - y_mean)
    if denom <= 0.0:
        return None
    return np.array([sx / denom, sy / denom])
