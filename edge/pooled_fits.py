"""The edge fits of ``edge.centre_offsets`` in a pool of worker processes, on :class:`~edge.centre_offsets.InlineFits`'
schedule: the same jobs at the same frames, each result entering the tracker the same number of frames after its job,
so a video's poses are the same bytes on every run (``edge-ips track``) while the frame loop runs on beside the fits.

A job goes to the pool when it is handed over and is waited for (blocking) only at the frame its result is due: with
``delay_frames`` of 15 and a fit every 10 frames, the loop and the fits overlap, and the first frames' fits (one a
frame until every rover has :data:`~edge.centre_offsets.MIN_SAMPLES` samples) spread over the workers.

The fit is a pure function of the job, so any job the pool does not deliver is fitted in this process instead, with
the same result: a worker that died or could not be started, or a fit not done after :data:`GUARD_S` (the first
such failure is logged, the pool is stopped, and the rest of the run fits inline), or a fit that raised in a worker
(run again here, where it raises as it would in the loop). The workers end with this process, however it ends
(:func:`~edge.orphans.exit_with_parent`).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool

from edge.centre_offsets import HELD_BACK_FRAMES, EdgeJob, EdgeSample, fit_offset
from edge.orphans import exit_with_parent

log = logging.getLogger(__name__)

GUARD_S = 120.0  # a fit (~0.1 s) not done after this long is taken as a stuck worker
MAX_WORKERS = 4  # more gains nothing: at most 1 + delay_frames / every_frames fits are due at once after the start


def default_workers() -> int:
    """One worker per core this process may run on, at most :data:`MAX_WORKERS`: while a result is due the frame
    loop only waits, so on two cores two workers fit (one leaves a core idle whenever the loop waits)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 2
    return max(1, min(MAX_WORKERS, cores))


class PooledFits:
    """Fits in ``workers`` processes (started on the first job), one every ``every_frames`` frames, each result
    released ``delay_frames`` after its job: :class:`~edge.centre_offsets.InlineFits`' schedule and results. ``fit``
    is the fit run per job (a module-level function: it is pickled to the workers)."""

    def __init__(
        self,
        every_frames: int = 10,
        delay_frames: int = HELD_BACK_FRAMES,
        workers: int | None = None,
        fit: Callable[[EdgeJob], EdgeSample | None] = fit_offset,
        guard_s: float = GUARD_S,
    ) -> None:
        self.every_frames = every_frames
        self.delay_frames = delay_frames
        self.workers = workers if workers is not None else default_workers()
        self.guard_s = guard_s
        self.inline = False  # after a failure of the pool: every job is fitted in this process
        self._fit = fit
        self._last: int | None = None
        self._pool: ProcessPoolExecutor | None = None
        # (release frame, job, its fit in the pool or None to fit here), in the order handed over
        self._pending: deque[tuple[int, EdgeJob, Future[EdgeSample | None] | None]] = deque()

    def ready(self, frame: int, hurry: bool = False) -> bool:
        return self._last is None or frame - self._last >= (1 if hurry else self.every_frames)

    def submit(self, job: EdgeJob) -> None:
        self._last = job.frame
        future: Future[EdgeSample | None] | None = None
        if not self.inline:
            try:
                if self._pool is None:
                    # spawn: a forked child would inherit the parent's threads half-way (see ProcessFits)
                    self._pool = ProcessPoolExecutor(
                        self.workers,
                        mp_context=multiprocessing.get_context("spawn"),
                        initializer=exit_with_parent,  # no orphans if this process is killed
                        initargs=(os.getpid(),),
                    )
                future = self._pool.submit(self._fit, job)
            except Exception as exc:  # the pool cannot start, or is broken (a worker died before this job)
                self._fail(f"a worker process could not take a job ({exc!r})")
        self._pending.append((job.frame + self.delay_frames, job, future))

    def collect(self, frame: int) -> list[EdgeSample]:
        out = []
        while self._pending and self._pending[0][0] <= frame:
            _, job, future = self._pending.popleft()
            sample = self._result(job, future)
            if sample is not None:
                out.append(sample)
        return out

    def _result(self, job: EdgeJob, future: Future[EdgeSample | None] | None) -> EdgeSample | None:
        """The job's sample: from the pool while it serves, else fitted here."""
        if future is not None and not self.inline:
            try:
                return future.result(timeout=self.guard_s)
            except FutureTimeout:
                if future.done():  # the fit itself raised a TimeoutError: the pool serves on
                    return self._fit(job)
                self._fail(f"a fit was not done after {self.guard_s:.0f} s")
            except BrokenProcessPool as exc:  # a worker died
                self._fail(f"a worker process died ({exc!r})")
            except Exception:  # the fit raised in the worker: the pool serves on; here it raises as in the loop
                pass
        return self._fit(job)

    def _fail(self, reason: str) -> None:
        """The pool failed: logged once, stopped, and the rest of the run fits in this process."""
        if not self.inline:
            log.warning("edge fits: %s; this and every later fit runs in the frame loop (same results)", reason)
        self.inline = True
        self._stop_pool()

    def _stop_pool(self) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        # a stuck or stopped worker does not end on shutdown: kill it (the executor has no public way to)
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    def worker_pids(self) -> list[int]:
        """The workers' process ids (none before the first job or after a failure)."""
        processes = getattr(self._pool, "_processes", None) or {}
        return [p.pid for p in processes.values() if p.pid is not None]

    def close(self) -> None:
        self._stop_pool()
        self._pending.clear()
