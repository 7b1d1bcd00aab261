"""LSGAN losses over the list of score maps of a multi-scale discriminator (as MUNIT).

    L_dis = sum_k mean((D_k(fake) - 0)^2) + mean((D_k(real) - 1)^2)
    L_gen = sum_k mean((D_k(fake) - 1)^2)

Means are over all elements of a scale's map (batch included); scales are summed.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


def lsgan_dis_loss(fake_outs: Sequence[torch.Tensor], real_outs: Sequence[torch.Tensor]) -> torch.Tensor:
    """Discriminator loss from ``D(fake)`` and ``D(real)`` score lists (fakes detached by the caller)."""
    if len(fake_outs) != len(real_outs) or not fake_outs:
        raise ValueError(f"need the same nonzero number of scales, got {len(fake_outs)} and {len(real_outs)}")
    return sum((f.square().mean() + (r - 1).square().mean() for f, r in zip(fake_outs, real_outs)))


def lsgan_gen_loss(fake_outs: Sequence[torch.Tensor]) -> torch.Tensor:
    """Generator loss: push ``D(fake)`` towards 1 at every scale."""
    if not fake_outs:
        raise ValueError("need at least one scale")
    return sum(((f - 1).square().mean() for f in fake_outs))
