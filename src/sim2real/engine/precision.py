"""Numeric format per device: bf16 autocast with channels-last images and weights on CUDA,
fp32 in the default layout on the CPU. Training and inference both ask here."""

from __future__ import annotations

import contextlib

import torch


def mixed_precision(device: torch.device) -> bool:
    """Whether ``device`` runs bf16 autocast and channels-last tensors: CUDA only. Tests switch
    it on for the CPU to exercise that path (CPU autocast has the same bf16 semantics)."""
    return device.type == "cuda"


def autocast(device: torch.device, enabled: bool):
    """bf16 autocast on ``device`` when ``enabled`` (no loss scaling is needed for bf16)."""
    if enabled:
        return torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext()
