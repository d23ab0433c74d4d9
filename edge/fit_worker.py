"""The edge fits of ``edge.centre_offsets`` in one worker process beside the frame loop (the appliance's): the frame
thread hands over a window now and then and collects what has finished, and the worker can fail as a process does."""

from __future__ import annotations

import logging
import multiprocessing
import os
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from edge.centre_offsets import STALL_FRAMES, EdgeJob, EdgeSample, fit_offset
from edge.orphans import exit_with_parent

log = logging.getLogger(__name__)


class ProcessFits:
    """Fits in one worker process (started on the first job), one job at a time and at most one every
    ``every_frames`` frames: the frame loop only copies a window and collects what has finished.

    The worker can fail as a process does: a fit that raises costs that sample; a worker that dies (killed, out of
    memory) or cannot be started costs the job, and the next job starts a new one after a pause that doubles with
    each failure in a row (``every_frames`` times 2, 4, ... 64); a fit still running after
    :data:`STALL_FRAMES` frames (a stopped or stuck worker) is abandoned and its worker terminated. Every failure is
    counted in ``failed`` and logged; the tracker keeps the offsets it has."""

    def __init__(self, every_frames: int = 10) -> None:
        self.every_frames = every_frames
        self.failed = 0  # jobs lost: a fit that raised, a worker that died, stalled or could not start
        self._last: int | None = None
        self._pool: ProcessPoolExecutor | None = None
        self._running: Future[EdgeSample | None] | None = None
        self._started = 0  # the frame the running job was handed over
        self._done: list[EdgeSample] = []
        self._failures_in_a_row = 0
        self._pause_until = 0
        log.info("edge offsets on: edge fits in a worker process, one rover's window every %d frames", every_frames)

    def ready(self, frame: int, hurry: bool = False) -> bool:
        if self._running is not None and not self._running.done():
            if frame - self._started < STALL_FRAMES:
                return False
            log.warning(
                "edge fits: a fit has run for %d frames; its worker is stopped and a new one started",
                frame - self._started,
            )
            self._lost(frame)
        if frame < self._pause_until:
            return False
        return self._last is None or frame - self._last >= (1 if hurry else self.every_frames)

    def submit(self, job: EdgeJob) -> None:
        self._harvest(job.frame)
        self._last = job.frame
        try:
            if self._pool is None:
                # spawn: the appliance runs threads (MQTT, HTTP), which a forked child would inherit half-way
                self._pool = ProcessPoolExecutor(
                    max_workers=1,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=exit_with_parent,
                    initargs=(os.getpid(),),
                )
            self._running = self._pool.submit(fit_offset, job)
            self._started = job.frame
        except Exception as exc:  # the pool cannot start or is broken (its worker died before this job)
            log.warning("edge fits: the worker process could not take a job (%s)", exc)
            self._lost(job.frame)

    def _lost(self, frame: int) -> None:
        """A job lost with its worker: stop the worker, count it, pause before the next."""
        self.failed += 1
        self._failures_in_a_row += 1
        self._pause_until = frame + self.every_frames * 2 ** min(self._failures_in_a_row, 6)
        self._stop_pool()

    def _harvest(self, frame: int = 0) -> None:
        running = self._running
        if running is None or not running.done():
            return
        self._running = None
        try:
            sample = running.result()
        except BrokenProcessPool:
            log.warning("edge fits: the worker process died; a new one starts with a later job")
            self._lost(frame)
            return
        except Exception as exc:  # the fit raised: that sample is lost, the worker serves on
            log.warning("edge fits: a fit failed (%s)", exc)
            self.failed += 1
            return
        self._failures_in_a_row = 0
        if sample is not None:
            self._done.append(sample)

    def collect(self, frame: int) -> list[EdgeSample]:
        self._harvest(frame)
        out, self._done = self._done, []
        return out

    def wait(self, timeout_s: float) -> bool:
        """Block until the running fit (if any) has finished; False on timeout."""
        running = self._running
        if running is None:
            return True
        done, _ = wait([running], timeout=timeout_s)
        return bool(done)

    def worker_pids(self) -> list[int]:
        """The worker's process id (none before the first job or after a failure)."""
        processes = getattr(self._pool, "_processes", None) or {}
        return [p.pid for p in processes.values() if p.pid is not None]

    def _stop_pool(self) -> None:
        pool, self._pool, self._running = self._pool, None, None
        if pool is None:
            return
        # a stuck or stopped worker does not end on shutdown: kill it (the executor has no public way to)
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.kill()  # SIGKILL: a stopped process would hold a SIGTERM until continued
        pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        self._stop_pool()
