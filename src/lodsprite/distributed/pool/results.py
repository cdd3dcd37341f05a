"""What both render pools (:class:`~.local_pool.LocalPool`, local processes;
:class:`~.ray_pool.RayPool`, Ray actors) share: the job table
(:class:`~.dispatch.JobTable`) and the side of their interface the web hub reads, the
results and a pipe that is readable while some wait (``loop.add_reader``)."""

from __future__ import annotations

import os
import time

from lodsprite.distributed.pool.dispatch import JobTable
from lodsprite.distributed.pool.jobs import Result, WorkerInfo

__all__ = ["PoolResults", "drain", "signal"]


class PoolResults:
    """The results side of a pool: :attr:`table`, :meth:`poll`, :meth:`fileno`,
    :meth:`workers`, :meth:`stats`, :meth:`wait_workers`.  The pool's own thread
    updates the table and calls :meth:`_changed` after the workers change."""

    def __init__(self, job_timeout_s: float) -> None:
        self.job_timeout_s = float(job_timeout_s)
        self._ready_r, self._ready_w = os.pipe()
        for fd in (self._ready_r, self._ready_w):
            os.set_blocking(fd, False)
        self._results_closed = False
        self.table = JobTable(self.job_timeout_s, self._signal)
        self._snapshot: list[WorkerInfo] = []

    def poll(self) -> list[Result]:
        """The results (successes and failures) since the last call; never blocks."""
        drain(self._ready_r)
        done = self.table.done
        return [done.popleft() for _ in range(len(done))]

    def fileno(self) -> int:
        """A descriptor readable while :meth:`poll` has results (level-triggered)."""
        return self._ready_r

    def workers(self) -> list[WorkerInfo]:
        """The workers ready now."""
        return list(self._snapshot)

    def stats(self) -> dict[str, float]:
        """Counts: jobs, results, failed, requeued (after a lost worker), declined
        (results not ok, each retried elsewhere or failed), dead, rejected, ignored; and
        the render capacity: ``busy_s`` (seconds workers spent on the jobs they answered,
        dispatch to answer, all workers together: over a wall-clock window and the
        worker count it gives their utilisation), ``job_ms_p50``/``job_ms_p90`` (a
        job's dispatch to answer, ms, over the last :data:`~.dispatch.JOB_TIMES`; None before
        one) and ``overhead_ms_p50``/``overhead_ms_p90`` (that time less the worker's own
        ``render_ms``: the pool's dispatch overhead per keyframe)."""
        return self.table.stats()

    def wait_workers(self, n: int, timeout: float) -> bool:
        """Wait until at least ``n`` workers are ready (at most ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while len(self._snapshot) < n and time.monotonic() < deadline:
            time.sleep(0.02)
        return len(self._snapshot) >= n

    def _changed(self) -> None:
        self._snapshot = self.table.snapshot()

    def _signal(self) -> None:
        if not self._results_closed:  # a descriptor closed may be another file's now
            signal(self._ready_w)

    def _close_results(self) -> None:
        self._results_closed = True
        for fd in (self._ready_r, self._ready_w):
            os.close(fd)


def signal(fd: int) -> None:
    """Make the pipe ``fd`` readable (a full or closed pipe is left as it is)."""
    try:
        os.write(fd, b"\x01")
    except (BlockingIOError, OSError):
        pass  # the pipe is full (a wake-up is pending anyway) or closed


def drain(fd: int) -> None:
    """Read the pipe ``fd`` empty."""
    try:
        while os.read(fd, 4096):
            pass
    except (BlockingIOError, OSError):
        pass
