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


def single_thread_worker(*_args) -> None:
    """Limit this process's BLAS/OpenMP pools (threadpoolctl) and torch to one thread each."""
    import sys

    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
