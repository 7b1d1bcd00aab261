"""Which device a command runs on, chosen at run time: ``--device auto|cpu|cuda``.

Training, translation and evaluation all ask here; it imports nothing of the training loop, so a
command that only runs a trained model does not load it."""

from __future__ import annotations

import torch

from sim2real.errors import UserError

DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str, local_rank: int = 0) -> torch.device:
    """``name`` as a torch.device: 'auto' is CUDA when a CUDA device is available, else the CPU;
    'cuda' takes device ``local_rank`` modulo the visible devices (one per torchrun rank) and
    makes it the current one. 'cuda' without a CUDA device, or any other name, is a
    :class:`UserError`."""
    if name not in DEVICES:
        raise UserError(f"device must be 'auto', 'cpu' or 'cuda', got '{name}'")
    if name == "cpu" or (name == "auto" and not torch.cuda.is_available()):
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise UserError("--device cuda was requested but no CUDA device is available (use --device auto or cpu)")
    device = torch.device("cuda", local_rank % torch.cuda.device_count())
    torch.cuda.set_device(device)
    return device
