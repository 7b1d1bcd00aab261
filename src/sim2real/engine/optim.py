"""A run's optimisers and learning-rate schedules: one Adam per parameter group of the method
(:meth:`Method.optim_groups`), each with StepLR halving its rate every ``optim.lr_halve_every``
steps (the paper's schedule)."""

from __future__ import annotations

import torch

from sim2real.config import TrainConfig


def adam(group, cfg: TrainConfig) -> torch.optim.Adam:
    """Adam for one of the method's groups: its learning rate, and its weight decay when it sets
    one (else ``optim.weight_decay``)."""
    wd = cfg.optim.weight_decay if group.weight_decay is None else group.weight_decay
    params, kw = group.params, dict(lr=group.lr, betas=(cfg.optim.beta1, cfg.optim.beta2), weight_decay=wd)
    try:  # fused Adam: 5x faster on the 23.6 M texture (CPU and CUDA)
        return torch.optim.Adam(params, fused=True, **kw)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(params, **kw)


Optimizers = dict[str, torch.optim.Optimizer]
Schedulers = dict[str, torch.optim.lr_scheduler.StepLR]


def optimizers_for(groups, cfg: TrainConfig) -> tuple[Optimizers, Schedulers]:
    """({group name: Adam}, {group name: StepLR}) for the method's parameter groups."""
    optimizers = {g.name: adam(g, cfg) for g in groups}
    schedulers = {name: torch.optim.lr_scheduler.StepLR(opt, cfg.optim.lr_halve_every, gamma=0.5)
                  for name, opt in optimizers.items()}
    return optimizers, schedulers
