"""L1 terms of the cycle, reconstruction and content losses (MUNIT's ``recon_criterion``).

    l1(x, y) = mean |x - y|   over every element (batch, channels, pixels).

For domain A the tex and ref channels are one tensor, so the paper's ``||(tex; ref)||_1`` is
``l1`` over the stacked channels.
"""

from __future__ import annotations

import torch


def l1(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    if x.shape != y.shape:
        raise ValueError(f"l1: shapes differ, {tuple(x.shape)} vs {tuple(y.shape)}")
    return (x - y).abs().mean()
