"""Spawned worker processes with a per-process state: the one process pool of the project.

Ray casting (Embree) and the stand-in real domain's shading run one core per process, so every
stage that renders many views uses :class:`WorkerPool`::

    with WorkerPool(workers, setup, (scene_geometry,)) as pool:
        for result in pool.imap(job_fn, jobs):
            ...

* ``setup(*args)`` runs once in each worker (after :func:`sim2real.threads.single_thread_worker`)
  and returns that process's state (a ray caster, materials, ...); ``job_fn(state, job)`` runs a
  job there. Both must be module-level functions (the workers are spawned, not forked: Embree
  and torch do not survive a fork), and ``args`` and jobs must pickle.
* ``workers <= 1`` runs everything in the calling process, in order, with no pool; ``state``
  may then hand over a state (not None) the caller already has (nothing is built twice).
* :meth:`WorkerPool.imap` yields results in job order, keeps at most ``in_flight`` jobs
  submitted but not yet consumed (memory stays bounded however many jobs, and a lazy iterable of
  jobs is drawn only as fast as the workers render), and re-raises a job's exception in the
  caller: a :class:`~sim2real.errors.UserError` in a worker (an unreadable scene in ``setup``
  too) reaches the command as its one-line error instead of a pool that restarts its workers
  for ever.
"""

from __future__ import annotations

import collections
import multiprocessing as mp
import pickle
from typing import Any, Callable, Iterable, Iterator

from sim2real.threads import single_thread_worker

_NO_STATE = object()
_state: Any = _NO_STATE
"""This worker process's state (the return value of ``setup``), or the exception it raised."""
_setup_error: BaseException | None = None


def _init(payload: bytes) -> None:
    global _state, _setup_error

    single_thread_worker()
    try:
        setup, args = pickle.loads(payload)
        _state, _setup_error = setup(*args), None
    except Exception as e:  # kept and raised by each job: a failing initializer would respawn forever
        _state, _setup_error = _NO_STATE, e


def _call(fn: Callable[[Any, Any], Any], job: Any) -> Any:
    if _setup_error is not None:
        raise _setup_error
    return fn(_state, job)


class WorkerPool:
    """``workers`` spawned processes, each with its own state (see the module docstring)."""

    def __init__(self, workers: int, setup: Callable[..., Any], args: tuple = (), state: Any = None,
                 in_flight: int | None = None):
        self.workers = max(1, int(workers))
        self._setup, self._args = setup, tuple(args)
        self._local = state
        self.in_flight = max(1, int(in_flight or 8 * self.workers))
        self._pool = None

    def __enter__(self) -> "WorkerPool":
        if self.workers > 1:

            # The workers start now (imports, setup) while the caller prepares its jobs. ``setup``
            # and its arguments travel pre-pickled: unpickled inside the start-up message, their
            # modules' imports (numpy: 0.3 s) would block the parent's write to each new worker
            # in turn, so the workers would start one after another.
            payload = pickle.dumps((self._setup, self._args), protocol=pickle.HIGHEST_PROTOCOL)
            self._pool = mp.get_context("spawn").Pool(self.workers, initializer=_init, initargs=(payload,))
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None

    def imap(self, fn: Callable[[Any, Any], Any], jobs: Iterable, in_flight: int | None = None) -> Iterator:
        """``fn(state, job)`` for every job, results in job order."""
        if self._pool is None:
            if self._local is None:
                self._local = self._setup(*self._args)
            for job in jobs:
                yield fn(self._local, job)
            return
        window = max(1, int(in_flight or self.in_flight))
        pending: collections.deque = collections.deque()
        for job in jobs:
            pending.append(self._pool.apply_async(_call, (fn, job)))
            if len(pending) >= window:
                yield pending.popleft().get()
        while pending:
            yield pending.popleft().get()
