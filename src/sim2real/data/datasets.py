"""The training dataset of a method's data kind, and the step sampler.

A method declares the kind of sample it trains on (:attr:`sim2real.methods.base.Method.data`):
``view_pairs`` and ``views`` (data/pairs.py), ``triplets`` (data/triplets.py). Views come from
``--scenes`` entries resolved by :func:`resolve_scenes` (data/sources.py). Every dataset is
indexed by the training step (:class:`StepSampler` yields the steps of a run).
"""

from __future__ import annotations

from typing import Iterator

import torch

from sim2real.config import DataConfig
from sim2real.data.pairs import PAIR_TRIES, TrainPairs
from sim2real.data.real import RealImages
from sim2real.data.sources import SceneSource, resolve_scenes
from sim2real.data.triplets import TrainTriplets

__all__ = ["DATA_KINDS", "PAIR_TRIES", "SceneSource", "StepSampler", "TrainPairs", "TrainTriplets", "make_dataset",
           "resolve_scenes"]


DATA_KINDS = ("view_pairs", "views", "triplets")
"""What a method may declare it trains on (:attr:`sim2real.methods.base.Method.data`):
view pairs with correspondences, single views (both with single real images), and triplets of
consecutive frames in both domains (data/triplets.py)."""


def make_dataset(kind: str, sources: list[SceneSource], real: RealImages, cfg: DataConfig, seed: int,
                 rank: int = 0) -> torch.utils.data.Dataset:
    """The step-indexed training dataset of kind ``kind`` (:data:`DATA_KINDS`)."""
    if kind not in DATA_KINDS:
        raise ValueError(f"unknown training data kind {kind!r} (known: {', '.join(DATA_KINDS)})")
    if kind == "triplets":
        return TrainTriplets(sources, real, cfg, seed, rank)
    return TrainPairs(sources, real, cfg, seed, rank, pairs=kind == "view_pairs")



class StepSampler(torch.utils.data.Sampler):
    """Yields the steps ``start, start + 1, ..., stop - 1``: one sample per training step."""

    def __init__(self, start: int, stop: int):
        self.start, self.stop = int(start), int(stop)

    def __iter__(self) -> Iterator[int]:
        return iter(range(self.start, self.stop))

    def __len__(self) -> int:
        return max(0, self.stop - self.start)
