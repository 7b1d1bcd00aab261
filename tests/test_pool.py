"""sim2real.pool.WorkerPool: results in job order, per-process state, bounded submission, errors
of a worker reach the caller (no pool that restarts failing workers for ever)."""

from __future__ import annotations

import os

import pytest

from sim2real.errors import UserError
from sim2real.pool import WorkerPool


def _setup(offset: int) -> dict:
    if offset < 0:
        raise UserError(f"bad offset {offset}")
    return {"offset": offset, "pid": os.getpid(), "jobs": 0}


def _job(state: dict, x: int) -> tuple[int, int, int]:
    state["jobs"] += 1  # the state persists between the jobs of one process
    return x + state["offset"], state["pid"], state["jobs"]


def test_two_workers_keep_job_order_and_own_state():
    with WorkerPool(2, _setup, (100,)) as pool:
        out = list(pool.imap(_job, range(40), in_flight=3))
    assert [r[0] for r in out] == [x + 100 for x in range(40)]
    pids = {r[1] for r in out}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    for pid in pids:  # each process counts its own jobs: 1, 2, 3, ... in the order it ran them
        counts = [r[2] for r in out if r[1] == pid]
        assert sorted(counts) == list(range(1, len(counts) + 1))


def test_in_process_uses_the_given_state_and_runs_setup_only_without_one():
    state = {"offset": 5, "pid": os.getpid(), "jobs": 0}
    with WorkerPool(1, _setup, (-1,), state=state) as pool:  # setup would raise: it must not run
        assert [r[0] for r in pool.imap(_job, [1, 2])] == [6, 7]
    assert state["jobs"] == 2
    with WorkerPool(1, _setup, (3,)) as pool:
        assert [r[:1] for r in pool.imap(_job, [1])] == [(4,)]


def test_lazy_jobs_are_drawn_only_as_far_as_the_window():
    drawn = []

    def jobs():
        for x in range(20):
            drawn.append(x)
            yield x

    with WorkerPool(2, _setup, (0,)) as pool:
        it = pool.imap(_job, jobs(), in_flight=4)
        assert next(it)[0] == 0
        assert len(drawn) == 4  # the first result comes back once 4 jobs are in flight
        assert [r[0] for r in it] == list(range(1, 20))


def test_a_failing_setup_raises_in_the_caller():
    with pytest.raises(UserError, match="bad offset -1"):
        with WorkerPool(2, _setup, (-1,)) as pool:
            list(pool.imap(_job, range(4)))


def _thread_counts(state: dict, _job) -> tuple[list[int], int]:
    import numpy  # noqa: F401  (loads OpenBLAS now: after the worker started, as ray casting does)
    import torch
    from threadpoolctl import threadpool_info

    return sorted({d["num_threads"] for d in threadpool_info()}), torch.get_num_threads()


def test_workers_run_one_thread_even_for_libraries_loaded_after_start_up(monkeypatch):
    """A worker whose main module has not loaded numpy (the ``sim2real`` entry point) loads it
    only while running its jobs: OpenBLAS and torch must start single-threaded there too. Two
    OpenBLAS threads in each of two ray-casting workers halved ``sim2real render``'s rate."""
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    with WorkerPool(2, _setup, (0,)) as pool:
        out = list(pool.imap(_thread_counts, range(2)))
    assert out == [([1], 1), ([1], 1)]
