"""G-buffers of a frame sequence, streamed: ray casting in order, in-process or in a process pool,
chunk by chunk, so that long trajectories never sit in memory at once.

This module imports no torch: the spawned ray-casting workers load only numpy and Embree (and
trimesh when no caster is given, to load the scene themselves).
"""

from __future__ import annotations

import os
from typing import Iterable, Iterator, Sequence

from sim2real.pool import WorkerPool
from sim2real.render.gbuffer import GBuffer
from sim2real.render.raycast import caster_setup, render_camera
from sim2real.threads import usable_cores, worker_count

POOL_MIN_RAYS = 32 * 256 * 512
"""Below this many rays in all (about 2-3 s of casting on one core) the rays are cast in-process:
starting spawned workers (each loads the scene and builds its BVH) costs about as much."""


def auto_workers(cameras: Sequence) -> int:
    """Ray-casting processes for ``cameras``: 1 (in-process) for short or small sequences or on
    one core, else the project's worker rule (:func:`sim2real.threads.worker_count`: every core
    of this process's share, at most one per frame)."""
    rays = sum(int(c.height) * int(c.width) for c in cameras)
    if rays < POOL_MIN_RAYS or usable_cores() < 2 or len(cameras) < 4:
        return 1
    return worker_count(jobs=len(cameras))


def iter_gbuffers(scene_dir: str | os.PathLike, cameras: Sequence, workers: int | None = None, chunk: int = 8,
                  caster=None) -> Iterator[GBuffer]:
    """Ray-cast ``cameras`` of the scene at ``scene_dir`` and yield their G-buffers in order.

    ``workers`` = 1 casts in this process (reusing ``caster`` when given); more starts a spawn pool
    of that many processes (one Embree caster each, :class:`sim2real.pool.WorkerPool`). At most
    two chunks (``chunk`` frames, at least two per worker) are rendered ahead of the caller, so
    memory stays bounded however long the trajectory. ``None`` picks :func:`auto_workers`.
    """
    cameras = list(cameras)
    workers = auto_workers(cameras) if workers is None else max(1, int(workers))
    if len(cameras) <= 1:
        workers = 1
    # The workers get the caller's geometry when there is a caster (no scene load, no trimesh).
    source = caster.geometry if caster is not None else str(scene_dir)
    with WorkerPool(workers, caster_setup, (source,), state=caster) as pool:
        yield from pool.imap(render_camera, cameras, in_flight=2 * max(int(chunk), 2 * workers))


def iter_view_files(files: Iterable[str | os.PathLike]) -> Iterator[GBuffer]:
    for path in files:
        yield GBuffer.load(path)


def chunked(items: Iterable, size: int) -> Iterator[list]:
    buf: list = []
    for item in items:
        buf.append(item)
        if len(buf) >= size:
            yield buf
            buf = []
    if buf:
        yield buf
