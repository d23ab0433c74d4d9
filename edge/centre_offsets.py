"""Centres referred to the marker's fitted edges: the fast centre's camera-dependent offset, learned off the frame
thread from occasional full edge fits (the ``edge_offsets`` tracker setting; ``docs/tracking.md``).

The coverage centre (``edge.coverage``) is cheap and steady, but a stream's chroma spread (4:2:0, coarse chroma
quantisation) moves it by 0.1-0.4 cm, by an amount the camera, the marker's colour and the rover's body decide: most
of it changes slowly across the floor (what changes faster, as a rover stops or turns on the spot, is left). The
full fit of the marker's edges in the
camera's encoded chroma (``edge.edges_encoded``) takes that spread out, but costs about 0.1 s per marker. So every
``every_frames`` frames one rover's window (as the camera gave it) goes to a worker that fits its edges; the fitted
centre minus the fast centre of that frame is a sample of the rover's offset at that place. Each frame the rover's
fast centre moves by what its samples say there: the samples' mean weighted by their distance on the floor,
shrunk to the rover's median offset where few are near; samples taken at one place count together as one.
A rover's first samples move it by a share of their offset, as many thirds as it has samples (:data:`MIN_SAMPLES`);
a sample far from the rover's others (another rover in the band beyond the edges, a fit run off) is not used, and
:data:`TRUST_CM` of every offset is held back (the fits' own error on some bodies and cameras).

The fits run in another process (``edge.fit_worker.ProcessFits``: the frame loop keeps its time) or, for benchmarks and
offline runs that must repeat exactly, in the frame loop with their results held back as long as a worker would
take (:class:`InlineFits`); ``edge.pooled_fits`` runs that schedule in a pool of worker processes (``edge-ips track``).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from edge.edges_encoded import encoded_edge_centre
from edge.rover_track import RoverTrack
from edge.trackers.base import Measurement
from edge.trackers.plane import PlaneGrid
from edge.trackers.window import Window

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)

MIN_SAMPLES = 3  # samples of a rover before its centre moves by their whole offset (by a share of it before)
JOB_MIN_COHERENCE = 0.5  # a window goes to the fits only when its marker's edges showed the axis clearly
MAX_OFFSET_CM = 1.0  # a fitted centre farther than this from the fast one ...
MAX_OFFSET_PX = 0.9  # ... and farther than this in the image is a failed fit, not an offset
MAX_RMS = 12.0  # a fit whose residual (8-bit units) is larger did not find a marker's edges
NEAR_CM = 60.0  # the floor distance over which an offset is taken to hold (the kernel's sigma)
PRIOR_WEIGHT = 1.0  # the rover's median offset counts as this many samples at the place asked about
OUTLIER_CM = 0.25  # a sample this far from the rover's median offset (and 3 spreads) is not used
SAME_PLACE_CM = 2.0  # samples this close together were taken at one place: together they count as one
KEEP = 200  # samples kept per rover (the newest)
TRUST_CM = 0.03  # the fits' own error on some cameras and bodies: this much of an offset is not applied
INSET_CM = 2.0  # the marker's colour is read this far inside its nominal outline (at most a quarter of its width)
MIN_INTERIOR_PX = 20
STALL_FRAMES = 300  # ProcessFits: a fit running this long (10 s at 30 fps; one takes ~0.1 s) is abandoned
HELD_BACK_FRAMES = 15  # InlineFits: a result reaches the tracker this late, as from a worker (~0.2-0.5 s per fit)


@dataclass(frozen=True)
class EdgeJob:
    """One rover's window for a full edge fit: ``raw`` (h, w, 3) the crop as the camera gave it, ``xy_cm`` (2, h, w)
    its pixels' centres on the marker plane, ``centre_cm`` the fast centre and ``axis_rad`` the long axis of that
    frame, ``size_cm`` the marker's length and width; ``index`` the rover, ``frame`` the frame's number;
    ``sharpened``: the camera may sharpen its luma (the fit weighs its luma by its residuals,
    ``edge.edges_encoded``)."""

    index: int
    frame: int
    raw: NDArray[np.uint8]
    xy_cm: FloatArray
    centre_cm: tuple[float, float]
    axis_rad: float
    size_cm: tuple[float, float]
    sharpened: bool = True


@dataclass(frozen=True)
class EdgeSample:
    """A fit's result: rover ``index`` at ``xy_cm``, its ``offset_cm`` (the fitted centre minus ``xy_cm``), the frame
    it came from. From the fit, ``xy_cm`` is that frame's fast centre; :meth:`CentreOffsets.collect` refers it to the
    rover's filtered centre of that frame where the tracker noted one."""

    index: int
    frame: int
    xy_cm: tuple[float, float]
    offset_cm: tuple[float, float]


def fit_offset(job: EdgeJob) -> EdgeSample | None:
    """The full edge fit of ``job`` as a sample, or None when the window does not show every side out to the band
    beyond the chroma's spread, or the fit did not find edges (its residual, or a centre beyond both
    :data:`MAX_OFFSET_CM` and :data:`MAX_OFFSET_PX`). Runs in the worker: a pure function of the job.

    The limit is in the image as well as on the plane: on the far side of the floor one pixel spans 2-3 cm along the
    view, and a marker there (a purple one on a white body, 4:2:0 q60) had its fast centre 1.5-2 cm off for three
    seconds while every fit that said so (0.5-0.8 pixels) was refused by a limit of 1 cm alone.

    The marker's colour is the mean of the pixels :data:`INSET_CM` inside its outline placed at the fast centre
    along its axis, not of the pixels classified as its hue: at 4:2:0 the marker's chroma spills onto a dark body,
    whose pixels then take the marker's hue at a fraction of its brightness."""
    interior = marker_interior(job, job.centre_cm)
    if int(np.count_nonzero(interior)) < MIN_INTERIOR_PX:
        return None
    fitted = encoded_edge_centre(
        job.raw, job.xy_cm, interior, job.centre_cm, job.axis_rad, job.size_cm, True, job.sharpened
    )
    if fitted is None:
        return None
    (x, y), fit = fitted
    dx, dy = x - job.centre_cm[0], y - job.centre_cm[1]
    if not (math.isfinite(dx) and math.isfinite(dy)) or fit.rms > MAX_RMS:
        return None
    if math.hypot(dx, dy) > MAX_OFFSET_CM and image_px(job.xy_cm, job.centre_cm, (dx, dy)) > MAX_OFFSET_PX:
        return None
    return EdgeSample(job.index, job.frame, job.centre_cm, (dx, dy))


def marker_interior(job: EdgeJob, at_cm: tuple[float, float]) -> NDArray[np.bool_]:
    """(h, w) the job's pixels :data:`INSET_CM` (at most a quarter of its width) inside the marker's outline placed
    at ``at_cm`` along the job's axis: where its colour is read."""
    c, s = math.cos(job.axis_rad), math.sin(job.axis_rad)
    dx, dy = job.xy_cm[0] - at_cm[0], job.xy_cm[1] - at_cm[1]
    inset = min(INSET_CM, 0.25 * min(job.size_cm))
    return np.asarray(
        (np.abs(dx * c + dy * s) < job.size_cm[0] / 2 - inset) & (np.abs(dy * c - dx * s) < job.size_cm[1] / 2 - inset)
    )


def image_px(xy_cm: FloatArray, at_cm: tuple[float, float], d_cm: tuple[float, float]) -> float:
    """How many image pixels the step ``d_cm`` on the plane spans at ``at_cm`` (``xy_cm`` (2, h, w): a window's
    pixels' centres on the plane; the nearest pixel's steps to its neighbours give the local scale); inf where the
    window is too small to tell."""
    h, w = xy_cm.shape[1:]
    if h < 2 or w < 2:
        return math.inf
    near = (xy_cm[0] - at_cm[0]) ** 2 + (xy_cm[1] - at_cm[1]) ** 2
    row, col = np.unravel_index(int(np.argmin(near)), near.shape)
    r, c = min(int(row), h - 2), min(int(col), w - 2)
    step_u = xy_cm[:, r, c + 1] - xy_cm[:, r, c]  # cm per pixel along image columns and rows
    step_v = xy_cm[:, r + 1, c] - xy_cm[:, r, c]
    jacobian = np.column_stack([step_u, step_v])
    if abs(float(np.linalg.det(jacobian))) < 1e-12:
        return math.inf
    return float(np.hypot(*np.linalg.solve(jacobian, np.asarray(d_cm, dtype=np.float64))))


class OffsetMap:
    """One rover's offset samples and the offset they give at a place on the floor."""

    def __init__(self) -> None:
        self.samples: deque[EdgeSample] = deque(maxlen=KEEP)
        self._cache: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None = None

    def add(self, sample: EdgeSample) -> None:
        self.samples.append(sample)
        self._cache = None

    def _usable(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(n, 2) places, (n, 2) offsets and (n,) weights of the samples that agree with the rover's others, and the
        median offset.

        Samples taken at one place (the rover standing, or sampled in quick succession while it has too few) see the
        same floor and neighbours, so they repeat one error (a tile's joint along an edge, another rover in the band
        beyond it): each counts as a share of one, the place's samples together as one (declustering), in the median
        and in the offset at a place alike. Five samples of a rover waiting at its start, 0.3-0.6 cm off where a
        joint ran along its far edge, would otherwise outvote every later sample."""
        if self._cache is None:
            xy = np.array([s.xy_cm for s in self.samples], dtype=np.float64).reshape(-1, 2)
            d = np.array([s.offset_cm for s in self.samples], dtype=np.float64).reshape(-1, 2)
            gap = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
            share = 1.0 / np.count_nonzero(gap <= SAME_PLACE_CM, axis=1)
            median = np.array([_weighted_median(d[:, 0], share), _weighted_median(d[:, 1], share)])
            far = np.hypot(*(d - median).T)
            spread = _weighted_median(far, share) * 1.4826
            keep = far <= max(OUTLIER_CM, 3.0 * spread)
            self._cache = (xy[keep], d[keep], share[keep], median)
        return self._cache

    def offset(self, x_cm: float, y_cm: float) -> tuple[float, float] | None:
        """The offset to add to a fast centre at (x, y), or None before the first sample. With fewer than
        :data:`MIN_SAMPLES` samples, a share of it (one sample: a third): over the family's seeds 1000 and 4321 the
        worst colour's bias 0.278 -> 0.264 cm, mean and p95 the same or lower on 16 runs of 18 against nothing
        moved before the third (``docs/benchmarks.md``)."""
        if not self.samples:
            return None
        xy, d, share, median = self._usable()
        if len(xy) == 0:
            return None
        w = share * np.exp(-((xy[:, 0] - x_cm) ** 2 + (xy[:, 1] - y_cm) ** 2) / (2.0 * NEAR_CM * NEAR_CM))
        total = float(w.sum()) + PRIOR_WEIGHT
        dx = (float(w @ d[:, 0]) + PRIOR_WEIGHT * float(median[0])) / total
        dy = (float(w @ d[:, 1]) + PRIOR_WEIGHT * float(median[1])) / total
        first = min(1.0, len(self.samples) / MIN_SAMPLES)
        dx, dy = dx * first, dy * first
        size = math.hypot(dx, dy)
        keep = max(0.0, 1.0 - TRUST_CM / size) if size > 0 else 0.0
        return dx * keep, dy * keep


def _weighted_median(values: FloatArray, weights: FloatArray) -> float:
    """The value below which half the weight lies (the lower one where it falls between two)."""
    return float(np.quantile(values, 0.5, weights=weights, method="inverted_cdf"))


class Fits(Protocol):
    """Where the fits run: jobs in, samples out."""

    def ready(self, frame: int, hurry: bool = False) -> bool:
        """May a job be handed over at ``frame``? ``hurry``: a rover has too few samples for its centre to move yet
        (the next fit as soon as the worker is free)."""
        ...

    def submit(self, job: EdgeJob) -> None: ...

    def collect(self, frame: int) -> list[EdgeSample]:
        """The samples whose fits have finished by ``frame`` (each once)."""
        ...

    def close(self) -> None: ...


class InlineFits:
    """Fits in the frame loop, one every ``every_frames`` frames, each result released ``delay_frames`` after its
    job as if a worker had taken that long: runs that repeat exactly (benchmarks; ``edge-ips track`` runs this schedule
    in worker processes, ``edge.pooled_fits.PooledFits``)."""

    def __init__(self, every_frames: int = 10, delay_frames: int = HELD_BACK_FRAMES) -> None:
        self.every_frames = every_frames
        self.delay_frames = delay_frames
        self._last: int | None = None
        self._pending: deque[tuple[int, EdgeSample]] = deque()

    def ready(self, frame: int, hurry: bool = False) -> bool:
        return self._last is None or frame - self._last >= (1 if hurry else self.every_frames)

    def submit(self, job: EdgeJob) -> None:
        self._last = job.frame
        sample = fit_offset(job)
        if sample is not None:
            self._pending.append((job.frame + self.delay_frames, sample))

    def collect(self, frame: int) -> list[EdgeSample]:
        out = []
        while self._pending and self._pending[0][0] <= frame:
            out.append(self._pending.popleft()[1])
        return out

    def close(self) -> None:
        self._pending.clear()


class CentreOffsets:
    """The offsets of every rover, which rover's window goes to the fits next (the one sampled longest ago), and the
    pipeline's steps with them each frame: :meth:`start_frame`, :meth:`corrected` per one-colour measurement,
    :meth:`filtered` once the rover's filter has taken it. ``sharpened``: the camera may sharpen its luma
    (``TrackerConfig.camera_sharpens``; each job says so to its fit)."""

    def __init__(self, fits: Fits, sharpened: bool = True) -> None:
        self.fits, self.sharpened = fits, sharpened
        self.maps: dict[int, OffsetMap] = {}
        self._turn: dict[int, int] = {}  # the frame of each rover's last turn: its window sent, or passed over
        self._refs: dict[tuple[int, int], tuple[float, float]] = {}
        self._frame = 0
        self._pick: int | None = None  # whose window goes to the fits this frame
        self._sent: int | None = None  # whose window went
        self._logged: set[int] = set()

    def start_frame(self, frame: int, tracks: list[RoverTrack]) -> None:
        """Take in the finished fits and choose this frame's window among the tracked one-colour rovers."""
        if self._pick is not None:  # picked, but not measured last frame (hidden, coasting): its turn passed
            self._turn[self._pick] = self._frame
        self._frame, self._sent = frame, None
        self.collect(frame)
        one_colour = [tr.index for tr in tracks if tr.filter is not None and tr.config.front_color_bgr is None]
        self._pick = self.pick(frame, one_colour)

    def corrected(
        self, window: Window, m: Measurement, tr: RoverTrack, grid: PlaneGrid, size_cm: tuple[float, float]
    ) -> Measurement:
        """A one-colour marker's measurement with its centre moved by the rover's learned offset; its window handed to
        the fits when it is this rover's turn. The rover's filter is shifted with each change of the offset (a new
        offset is no spike)."""
        if tr.index == self._pick and m.axis_coherence < JOB_MIN_COHERENCE:
            # its turn passes: held for it, the fits would idle until its edges show the axis (a magenta marker on
            # wood, coherence 0.36 in most frames, held eight rovers' fits for 117 of 300 frames)
            self._turn[tr.index], self._pick = self._frame, None
        elif tr.index == self._pick:
            x0, y0, x1, y1 = window.box
            raw = window.raw if window.raw is not None else window.bgr
            xy = np.stack([grid.x_cm[y0:y1, x0:x1], grid.y_cm[y0:y1, x0:x1]]).astype(np.float64)
            self.submit(
                EdgeJob(
                    tr.index,
                    self._frame,
                    np.array(raw, dtype=np.uint8, copy=True),
                    xy,
                    m.xy_cm,
                    m.axis_rad,
                    size_cm,
                    self.sharpened,
                )
            )
            self._pick, self._sent = None, tr.index
        shift = self.offset(tr.index, *m.xy_cm)
        if shift is None:
            return m
        if tr.filter is not None:
            tr.filter.shift(shift[0] - tr.offset_cm[0], shift[1] - tr.offset_cm[1])
        if tr.index not in self._logged and math.hypot(*shift) >= 0.01:  # once per rover
            self._logged.add(tr.index)
            log.info(
                "rover %s: centre corrected by (%+.2f, %+.2f) cm from %d edge fits",
                tr.config.id,
                *shift,
                self.samples(tr.index),
            )
        tr.offset_cm = shift
        return replace(m, xy_cm=(m.xy_cm[0] + shift[0], m.xy_cm[1] + shift[1]))

    def filtered(self, tr: RoverTrack, ahead_cm: tuple[float, float] = (0.0, 0.0)) -> None:
        """The rover's filter has taken this frame's measurement: if its window went to the fits, the fit's sample is
        taken against the filtered (uncorrected) centre (:meth:`note_reference`), moved on by ``ahead_cm`` to when
        its row was exposed (a rolling shutter: the window shows it there)."""
        if tr.index == self._sent and tr.filter is not None:
            fx, fy = tr.filter.position
            ref = (fx - tr.offset_cm[0] + ahead_cm[0], fy - tr.offset_cm[1] + ahead_cm[1])
            self.note_reference(tr.index, self._frame, ref)

    def note_reference(self, index: int, frame: int, xy_cm: tuple[float, float]) -> None:
        """The rover's filtered (uncorrected) position in the frame its window went to the fits: the sample is taken
        against it rather than against that frame's single measurement, whose own scatter would ride along."""
        self._refs[(index, frame)] = xy_cm

    def pick(self, frame: int, candidates: list[int]) -> int | None:
        """The rover whose window should go to the fits this frame, among ``candidates`` (being tracked)."""
        if not candidates:
            return None
        hurry = any(self.samples(i) < MIN_SAMPLES for i in candidates)
        if not self.fits.ready(frame, hurry):
            return None
        return min(candidates, key=lambda i: (self.samples(i) >= MIN_SAMPLES, self._turn.get(i, -1), i))

    def submit(self, job: EdgeJob) -> None:
        self._turn[job.index] = job.frame
        self.fits.submit(job)

    def collect(self, frame: int) -> int:
        """Take in the fits finished by ``frame``; the number of samples taken."""
        samples = self.fits.collect(frame)
        for s in samples:
            ref = self._refs.pop((s.index, s.frame), None)
            if ref is not None:
                fitted = (s.xy_cm[0] + s.offset_cm[0], s.xy_cm[1] + s.offset_cm[1])
                s = EdgeSample(s.index, s.frame, ref, (fitted[0] - ref[0], fitted[1] - ref[1]))
            self.maps.setdefault(s.index, OffsetMap()).add(s)
        for key in [k for k in self._refs if k[1] < frame - STALL_FRAMES]:
            del self._refs[key]
        return len(samples)

    def offset(self, index: int, x_cm: float, y_cm: float) -> tuple[float, float] | None:
        offsets = self.maps.get(index)
        return None if offsets is None else offsets.offset(x_cm, y_cm)

    def samples(self, index: int) -> int:
        offsets = self.maps.get(index)
        return 0 if offsets is None else len(offsets.samples)

    def reset(self) -> None:
        self.maps.clear()
        self._turn.clear()
        self._refs.clear()
        self._logged.clear()
        self._pick = self._sent = None

    def close(self) -> None:
        self.fits.close()
