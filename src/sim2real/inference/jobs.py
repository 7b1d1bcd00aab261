"""Threads for the evaluation's numpy and OpenCV work: the ceiling's and the floor's shading, and
the scoring of each row (Farnebäck, ORB, the essential matrix), which release the GIL for most of
their time. Every job is a deterministic function of its inputs, so its result does not depend
on the thread it ran on or on the order the jobs finished in: the figures are those of one
thread (tests/test_evaluate_speed.py compares them).

The number of threads follows the project's worker rule (:func:`sim2real.threads.worker_count`:
the cores of this process's share); on one core the jobs run in the calling thread, in order.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable

from sim2real.threads import worker_count


class Jobs:
    """``submit(fn, *args)`` returns a handle whose ``result()`` is ``fn(*args)``; with
    ``workers`` 1 the call runs at once in the calling thread. Use as a context manager: leaving
    it waits for every job."""

    def __init__(self, workers: int | None = None):
        self.workers = worker_count() if workers is None else max(1, int(workers))
        self._pool = ThreadPoolExecutor(self.workers) if self.workers > 1 else None

    def submit(self, fn: Callable[..., Any], *args, **kwargs) -> Future:
        if self._pool is not None:
            return self._pool.submit(fn, *args, **kwargs)
        f: Future = Future()
        f.set_result(fn(*args, **kwargs))
        return f

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)

    def __enter__(self) -> "Jobs":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def results(handles) -> list:
    """The results of a list of handles, in order (an exception of a job is raised here)."""
    return [h.result() for h in handles]
