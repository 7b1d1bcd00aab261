"""Shared memory of the training loader: what each worker may hold, and a clear error before a
loader would crash on a small ``/dev/shm``.

A DataLoader worker hands each finished sample to the training process through shared memory
(``/dev/shm`` on Linux); with ``prefetch_factor`` samples in flight per worker, the loader holds
up to ``workers * prefetch_factor`` samples there at once. A container's default ``/dev/shm`` is
64 MiB; past it the loader dies with a bus error or "No space left on device" from deep inside
torch. :func:`loader_workers_for_shm` checks the budget first.
"""

from __future__ import annotations

import os
import shutil

from sim2real.errors import UserError

SHM_DIR = "/dev/shm"
HEADROOM = 0.8
"""Share of the free shared memory the loader may plan to use (the rest: other processes, and
torch's own bookkeeping)."""
MiB = 2**20


def free_shared_memory(path: str = SHM_DIR) -> int | None:
    """Free bytes in ``path``, or None where there is no such file system (macOS, Windows)."""
    if not os.path.isdir(path):
        return None
    try:
        return int(shutil.disk_usage(path).free)
    except OSError:
        return None


def loader_workers_for_shm(workers: int, prefetch: int, sample_bytes: int, automatic: bool,
                           free: int | None = None) -> int:
    """The loader workers that fit the shared memory: ``workers`` when ``workers * prefetch``
    samples of ``sample_bytes`` fit in :data:`HEADROOM` of the free space; fewer when the count was
    ``automatic``; else (an explicit count, or not even one worker fits) a one-line
    :class:`UserError` that names the fixes. ``free`` defaults to ``/dev/shm``'s."""
    if workers <= 0:
        return workers
    free = free_shared_memory() if free is None else free
    if free is None:
        return workers
    per_worker = max(1, prefetch) * max(1, int(sample_bytes))
    fits = int(free * HEADROOM) // per_worker
    if workers <= fits:
        return workers
    if automatic and fits >= 1:
        return fits
    need = workers * per_worker
    raise UserError(
        f"{SHM_DIR} has {free / MiB:.0f} MiB free but {workers} loader worker(s) need about {need / MiB:.0f} MiB "
        f"({per_worker / MiB:.1f} MiB each); give the container more shared memory (docker run --shm-size=1g) "
        f"or use fewer workers (--set data.workers={max(0, fits)})")
