"""The training loader: how many workers (:func:`loader_workers`, bounded by the shared memory
their samples take, data/shm.py), what each worker sets up, and a worker's error as one line."""

from __future__ import annotations

import re
import sys

import torch

from sim2real.data.shm import loader_workers_for_shm
from sim2real.engine.runlock import close_inherited
from sim2real.engine.stop import ignore_in_worker
from sim2real.errors import UserError
from sim2real.threads import single_thread_worker, worker_count


def loader_workers(workers: int) -> int:
    """``data.workers`` with -1 (automatic) resolved by the project's worker rule
    (:func:`sim2real.threads.worker_count`): this rank's share of the node's cores, less one for
    the training process itself, at least 1, no fixed cap."""
    if workers >= 0:
        return workers
    return worker_count(reserve=1)


PREFETCH = 2
"""Samples each loader worker prepares ahead (its shared-memory bound: 2 x 8 MiB at most for a
paper-size pair, data/shm.py). With one worker per core a GPU step waits for none."""


def _worker_init(worker_id: int) -> None:
    """A DataLoader worker: one compute thread, no copy of the run lock, and SIGTERM / SIGINT
    left to the main process (engine/stop.py)."""
    single_thread_worker(worker_id)
    close_inherited()
    ignore_in_worker()


def worker_message(e: UserError) -> str:
    """The original message of a UserError re-raised by a DataLoader worker (one line)."""
    text = str(e)
    m = re.findall(r"UserError: (.*)", text)
    return m[-1] if "Original Traceback" in text and m else text


def make_loader(dataset, sampler, workers: int, pin_memory: bool,
                announce: bool) -> torch.utils.data.DataLoader:
    """A batch-1 DataLoader of ``dataset`` in ``sampler``'s order with ``workers`` (``data.workers``,
    -1 automatic) worker processes, fewer where /dev/shm holds no more of their samples (said on
    stderr when ``announce``; the count is the loader's ``num_workers``)."""
    wanted = loader_workers(workers)
    w = loader_workers_for_shm(wanted, PREFETCH, dataset.transfer_bytes(), automatic=workers < 0)
    if w < wanted and announce:
        print(f"sim2real: {w} loader workers instead of {wanted}: /dev/shm holds no more of their samples "
              "(docker run --shm-size=1g for all)", file=sys.stderr)
    return torch.utils.data.DataLoader(
        dataset, batch_size=1, sampler=sampler, num_workers=w, pin_memory=pin_memory,
        prefetch_factor=PREFETCH if w else None, persistent_workers=False, worker_init_fn=_worker_init if w else None,
    )
