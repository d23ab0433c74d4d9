"""Worker processes that end with the process that started them: a pool's initializer for the edge fits' workers
(``edge.fit_worker.ProcessFits``, ``edge.pooled_fits.PooledFits``)."""

from __future__ import annotations

import os
import select
import signal
import threading


def exit_with_parent(parent_pid: int) -> None:
    """A worker process's initializer (for a pool whose workers are the spawning process's children: the ``spawn``
    or ``fork`` context): end the worker when process ``parent_pid`` ends, however it ends (a ``kill -9``, a crash:
    no ``finally`` of the parent's runs then, and an idle worker would wait for jobs for ever). A thread waits on the
    parent's pidfd (Linux 5.3+), else polls the parent's id once a second. Ctrl-C is the parent's to handle (it stops
    its workers): a worker ignores SIGINT, which would otherwise come back as the fit's error."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        try:
            fd = os.pidfd_open(parent_pid)
        except (AttributeError, OSError):  # not Linux, an older kernel, or the parent gone already
            while os.getppid() == parent_pid:
                threading.Event().wait(1.0)
            os._exit(0)
        try:
            if os.getppid() == parent_pid:  # not a later process that took the parent's pid (the fd is of the pid)
                poller = select.poll()
                poller.register(fd, select.POLLIN)
                poller.poll()  # readable once the parent has ended
        finally:
            os._exit(0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
