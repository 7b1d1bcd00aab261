"""Multi-GPU / multi-node training with PyTorch DDP, started by ``torchrun``.

``torchrun`` sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK`` and the rendezvous variables;
:func:`setup` then joins the process group (NCCL on CUDA, gloo on CPU). A process group that
the caller already initialised (tests use ``torch.multiprocessing.spawn`` with a ``file://``
store) is used as is. Without either, training runs in one process.

Each rank draws its own samples (the data seed includes the rank), so an iteration of W ranks
sees W view pairs and W real images; DDP averages the gradients. The neural textures of all
scenes are **replicated** on every rank (they live in the DDP-wrapped generator stage); a
rank's step touches only the texture of the scene it sampled, and DDP's all-reduce brings
every rank the same averaged texture gradient. Replication is simple and fine for tens of
scenes (a 512^2 texture of 5 objects is 94 MB, plus 2x for Adam). For many more scenes,
sharding (each rank owning a subset of the textures and sampling only those scenes, with the
translator still replicated) is the scale-out path; it is not implemented.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel as DDP

from sim2real.errors import UserError


@dataclass
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    owns_group: bool = False
    """True when :func:`setup` initialised the process group (and so destroys it)."""

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def env_world_size() -> int:
    try:
        return int(os.environ.get("WORLD_SIZE", "1"))
    except ValueError:
        raise UserError(f"WORLD_SIZE must be an integer, got {os.environ['WORLD_SIZE']!r}") from None


def setup(device_type: str) -> DistInfo:
    """Join (or reuse) the process group; a single process when there is none."""
    if dist.is_available() and dist.is_initialized():
        return DistInfo(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", dist.get_rank())))
    if env_world_size() <= 1:
        return DistInfo()
    backend = "nccl" if device_type == "cuda" else "gloo"
    dist.init_process_group(backend=backend)
    return DistInfo(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", "0")), owns_group=True)


def teardown(info: DistInfo) -> None:
    if info.owns_group and dist.is_initialized():
        dist.destroy_process_group()


def barrier(info: DistInfo) -> None:
    if info.enabled:
        dist.barrier()


def any_true(info: DistInfo, flag: torch.Tensor) -> bool:
    """True when ``flag`` (a 0-d bool tensor) is True on any rank; one host sync."""
    if info.enabled:
        flag = flag.to(torch.int32)
        dist.all_reduce(flag, op=dist.ReduceOp.MAX)
    return bool(flag.item())


def max_ints(info: DistInfo, values: list[int], device: torch.device) -> list[int]:
    """The element-wise maximum of ``values`` over all ranks (one all-reduce and one host sync);
    ``values`` itself in one process."""
    if not info.enabled:
        return list(values)
    t = torch.tensor(values, dtype=torch.int64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return [int(v) for v in t.tolist()]


def on_main(info: DistInfo, fn) -> None:
    """Run ``fn`` on rank 0 only; a UserError it raises is raised on every rank (no rank is left
    waiting in a collective)."""
    error = None
    if info.is_main:
        try:
            fn()
        except UserError as e:
            error = str(e)
    if info.enabled:
        box = [error]
        dist.broadcast_object_list(box, src=0)
        error = box[0]
    if error is not None:
        raise UserError(error)


def gather_objects(info: DistInfo, obj) -> list:
    if not info.enabled:
        return [obj]
    out = [None] * info.world_size
    dist.all_gather_object(out, obj)
    return out


def wrap(module: nn.Module, info: DistInfo, device: torch.device, find_unused: bool) -> nn.Module:
    """``module`` itself in one process, else a DistributedDataParallel wrapper around it."""
    if not info.enabled:
        return module

    ids = [device.index] if device.type == "cuda" else None
    return DDP(module, device_ids=ids, find_unused_parameters=find_unused)
