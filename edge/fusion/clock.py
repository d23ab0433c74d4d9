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
import zlib
from collections import deque
from dataclasses import dataclass

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
    # live, the offsets are solved again at most this often (data time), in the learning after a frame's poses are
    # out: a clock moves microseconds in that time, and solving on every message was a third of the fuser's work
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
    squares), ``b`` the pair's calibration disagreement in the overlap (cm), ``d = off_hi - off_lo`` (s).

    Plain floats (the symmetric 3 x 3 as its 6 distinct entries, unknowns ``(bx, by, d)``): numpy's overhead on
    arrays this small was most of the aligner's time."""

    n00: float = 0.0
    n01: float = 0.0
    n02: float = 0.0
    n11: float = 0.0
    n12: float = 0.0
    n22: float = 0.0
    r0: float = 0.0
    r1: float = 0.0
    r2: float = 0.0
    samples: int = 0
    t_s: float = 0.0  # data time of the last update (for forgetting)

    def add(self, y: tuple[float, float], v: tuple[float, float], w: tuple[float, float, float], fade: float) -> None:
        """Fade the evidence, then add ``y`` with design ``[[1, 0, vx], [0, 1, vy]]`` and weight ``w`` (the 2 x 2
        inverse covariance ``(xx, xy, yy)``)."""
        (y1, y2), (vx, vy), (w11, w12, w22) = y, v, w
        g1, g2 = w11 * vx + w12 * vy, w12 * vx + w22 * vy  # the design's third column times w
        self.n00 = self.n00 * fade + w11
        self.n01 = self.n01 * fade + w12
        self.n02 = self.n02 * fade + g1
        self.n11 = self.n11 * fade + w22
        self.n12 = self.n12 * fade + g2
        self.n22 = self.n22 * fade + g1 * vx + g2 * vy
        self.r0 = self.r0 * fade + w11 * y1 + w12 * y2
        self.r1 = self.r1 * fade + w12 * y1 + w22 * y2
        self.r2 = self.r2 * fade + g1 * y1 + g2 * y2

    def estimate(self, seam_sigma_cm: float) -> tuple[float, float] | None:
        """``(d, variance of d)``, with the prior that the calibrations agree to ``seam_sigma_cm``; None when the
        data cannot tell a time offset from a seam (every rover crossed it one way at one speed).

        ``d`` is eliminated last: with ``A`` the seam's block (prior added) and ``n`` its coupling to ``d``, the
        variance of ``d`` is ``1 / (n22 - n^T A^-1 n)`` (the Schur complement)."""
        prior = 1.0 / seam_sigma_cm**2
        a, b, c = self.n00 + prior, self.n01, self.n11 + prior
        det = a * c - b * b
        if not det > 0.0:
            return None
        # A^-1 n and A^-1 r[:2]
        p0, p1 = (c * self.n02 - b * self.n12) / det, (a * self.n12 - b * self.n02) / det
        schur = self.n22 - (self.n02 * p0 + self.n12 * p1)
        if not (math.isfinite(schur) and schur > 0.0):
            return None
        return (self.r2 - (p0 * self.r0 + p1 * self.r1)) / schur, 1.0 / schur


@dataclass(slots=True)
class _Sample:
    t_local_s: float
    x: float
    y: float
    var: tuple[float, float, float]  # (xx, xy, yy) cm^2


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
        if self._dirty and self._data_s - self._solved_s >= s.solve_every_s:
            self.solve()  # here, in the learning, not in offset_s: live that is between a frame and its poses
        fixed = self.interpolate_with
        # held for the whole frame
        offsets = {b: fixed.get(b, 0.0) if fixed is not None else self.offset_s(b) for b in self._boards}
        for r in d.rovers:
            sample = _Sample(d.t_capture_s, r.xy_cm[0], r.xy_cm[1], r.cov_cm2)
            by_board = self._tracks.setdefault(r.rover_id, {})
            track = by_board.setdefault(d.edge_id, deque())
            key = (r.rover_id, d.edge_id)
            last = self._compared.get(key)
            if last is None:  # each rover's comparisons at its own phase: not every rover's in one frame
                last = self._compared[key] = sample.t_local_s - s.compare_every_s * _phase(key)
            due = sample.t_local_s - last >= s.compare_every_s
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
        used = sign * (off_b - off_a)
        for sample in others:
            tau = sample.t_local_s - off_a + off_b  # board b's clock at the instant of a's sample, as estimated
            if not p0.t_local_s < tau <= p1.t_local_s:
                continue
            f = (tau - p0.t_local_s) / dt
            ex = sample.x - (p0.x + f * (p1.x - p0.x))
            ey = sample.y - (p0.y + f * (p1.y - p0.y))
            if math.hypot(ex, ey) > s.max_residual_cm:
                continue  # an association mistake, not a clock
            g, h = (1 - f) ** 2, f * f
            xx = sample.var[0] + g * p0.var[0] + h * p1.var[0]
            xy = sample.var[1] + g * p0.var[1] + h * p1.var[1]
            yy = sample.var[2] + g * p0.var[2] + h * p1.var[2]
            det = xx * yy - xy * xy
            if not det > 0.0:
                continue
            y = (sign * ex + v[0] * used, sign * ey + v[1] * used)  # = seam + v * d, in the pair's orientation
            self._add_pair(key, y, v, (yy / det, -xy / det, xx / det), sample.t_local_s)

    def _add_pair(
        self,
        key: tuple[str, str],
        y: tuple[float, float],
        v: tuple[float, float],
        w: tuple[float, float, float],
        t_s: float,
    ) -> None:
        pair = self._pairs.setdefault(key, _Pair())
        fade = math.exp(-max(0.0, t_s - pair.t_s) / self.settings.memory_s) if pair.samples else 1.0
        pair.add(y, v, w, fade)
        pair.samples += 1
        pair.t_s = max(pair.t_s, t_s)
        self._data_s = max(self._data_s, t_s)
        self._dirty = True

    # -- estimates --------------------------------------------------------------------------------------------------
    def offset_s(self, edge_id: str) -> float:
        """The board's offset as last solved (0 for a board never seen; a new board's solved at once), never below
        its arrival bound as it is now. :meth:`observe` solves again when ``solve_every_s`` of new evidence is in."""
        if self._dirty and edge_id not in self._estimates:
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


def _phase(key: tuple[str, str]) -> float:
    """A fixed fraction in [0, 1) for a (rover, board): the same in every run (a str's hash() is not)."""
    return (zlib.crc32("/".join(key).encode()) & 0xFFFF) / 65536.0


def _velocity(samples: list[_Sample]) -> tuple[float, float] | None:
    """cm/s: the least-squares slope of a track's positions over time; None with fewer than 4 samples."""
    n = len(samples)
    if n < 4:
        return None
    t_mean = sum(q.t_local_s for q in samples) / n
    x_mean = sum(q.x for q in samples) / n
    y_mean = sum(q.y for q in samples) / n
    denom = sx = sy = 0.0
    for q in samples:
        dt = q.t_local_s - t_mean
        denom += dt * dt
        sx += dt * (q.x - x_mean)
        sy += dt * (q.y - y_mean)
    if denom <= 0.0:
        return None
    return sx / denom, sy / denom
