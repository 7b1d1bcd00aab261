"""One compute thread per worker process.

A pool of N workers on N cores, each with its own multi-threaded OpenBLAS / OpenMP (numpy's
matrix products in the G-buffer path, torch's CPU kernels), oversubscribes the cores: on the
2-core dev machine two ray-casting workers rendered 19.7 views/s against 22.8 for one, and 42.1
with one thread each (benchmarks/bench_raycast.py). Every pool initializer and DataLoader
worker calls :func:`single_thread_worker` first.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

from threadpoolctl import threadpool_limits


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask: a cluster job's or container's
    share, which ``os.cpu_count`` does not see)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return os.cpu_count() or 1


def local_ranks() -> int:
    """Training processes on this node: torchrun's ``LOCAL_WORLD_SIZE``, 1 outside torchrun."""
    try:
        return max(1, int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    except ValueError:
        return 1


def worker_count(jobs: int | None = None, reserve: int = 0) -> int:
    """The project's one rule for how many worker processes a stage starts.

    The cores this process may use (:func:`usable_cores`) are shared evenly by the training
    processes of its node (:func:`local_ranks`: under ``torchrun --nproc-per-node G`` each rank
    gets ``cores // G``), less ``reserve`` for the calling process itself (the training loop
    reserves 1: it runs the optimiser and feeds the GPU); at most one worker per job (``jobs``,
    when known) and at least 1. There is no fixed cap: on a 64-core node with 8 GPUs each rank's
    loader gets 7 workers, on a 16-core single-GPU host 15. Every worker runs one compute thread
    (:func:`single_thread_worker`), so the workers never oversubscribe the cores."""
    per_rank = usable_cores() // local_ranks() - max(0, int(reserve))
    n = max(1, per_rank)
    if jobs is not None:
        n = min(n, max(1, int(jobs)))
    return n


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def single_thread_worker(*_args) -> None:
    """Limit this process's BLAS/OpenMP pools and torch to one thread each: those already loaded
    (threadpoolctl, ``torch.set_num_threads``) and those loaded later, which read the environment.

    The second half matters: a spawned worker of the ``sim2real`` entry point has not loaded numpy
    when this runs, so threadpoolctl finds no OpenBLAS to limit, and numpy loaded by the first job
    started two threads per worker; ``sim2real render`` then ran at 16 views/s instead of 34
    (benchmarks/bench_raycast.py, 2-core dev machine)."""
    for var in _THREAD_VARS:
        os.environ[var] = "1"
    threadpool_limits(limits=1)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)


TORCH_RNG_LOCK = threading.Lock()
"""Held while a network is initialised from torch's global generator (``fork_rng`` and
``manual_seed``): networks trained in parallel threads must not draw from each other's seed."""


@contextlib.contextmanager
def one_torch_thread():
    """torch on one CPU thread inside the block, then as before: a reduction's order, and so its
    rounding, depends on the thread count, and small networks gain nothing from a second thread
    on a busy machine (two threads spinning against other jobs ran 10x slower on the dev machine)."""
    # imported here, not at the top: torch-free worker processes import this module
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)

