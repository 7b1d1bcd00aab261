"""One compute thread per worker process.

A pool of N workers on N cores, each with its own multi-threaded OpenBLAS / OpenMP (numpy's
matrix products in the G-buffer path, torch's CPU kernels), oversubscribes the cores: on the
2-core dev machine two ray-casting workers rendered 19.7 views/s against 22.8 for one, and 42.1
with one thread each (benchmarks/bench_raycast.py). Every pool initializer and DataLoader
worker calls :func:`single_thread_worker` first.
"""

from __future__ import annotations

import os


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask: a cluster job's or container's
    share, which ``os.cpu_count`` does not see)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return os.cpu_count() or 1


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def single_thread_worker(*_args) -> None:
    """Limit this process's BLAS/OpenMP pools and torch to one thread each: those already loaded
    (threadpoolctl, ``torch.set_num_threads``) and those loaded later, which read the environment.

    The second half matters: a spawned worker of the ``sim2real`` entry point has not loaded numpy
    when this runs, so threadpoolctl finds no OpenBLAS to limit, and numpy loaded by the first job
    started two threads per worker; ``sim2real render`` then ran at 16 views/s instead of 34
    (benchmarks/bench_raycast.py, 2-core dev machine)."""
    import sys

    from threadpoolctl import threadpool_limits

    for var in _THREAD_VARS:
        os.environ[var] = "1"
    threadpool_limits(limits=1)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
