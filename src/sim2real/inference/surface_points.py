"""Surface points sampled from a video's ray-cast frames under a fixed budget, for the exports
that list points rather than pixels (the COLMAP model's points, the point tracks)."""

from __future__ import annotations

import threading

import numpy as np


class PointSampler:
    """Surface points of a video's frames, added from several threads in any frame order.

    Frame ``i`` offers the surface pixels of a ``step`` grid (its offset moves with ``i`` so that
    neighbouring frames do not sample the same pixels), in an order shuffled with the seed ``i``.
    All frames keep every ``thin``-th of them; ``thin`` doubles, and the stored frames are thinned
    alike, whenever more than ``budget`` points are held, so every frame keeps the same share (at
    least one point each: a video of more frames than ``budget`` keeps one per frame). The shuffle
    keeps a thinned frame's points spread over the image: every other point of a grid in raster
    order would be whole columns of it."""

    def __init__(self, budget: int, step: int):
        self.budget, self.step, self.thin = int(budget), int(step), 1
        self._frames: dict[int, tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]] = {}  # i -> rows, cols, fields
        self._count = 0
        self._lock = threading.Lock()

    def add(self, i: int, mask: np.ndarray, **fields: np.ndarray) -> None:
        """Frame ``i``'s surface mask (H, W) and per-pixel fields (H, W, ...), e.g. its world points."""
        s = self.step
        h, w = mask.shape
        r0, c0 = (i * 3) % s, (i * 5) % s
        rows, cols = np.meshgrid(np.arange(r0, h, s), np.arange(c0, w, s), indexing="ij")
        keep = mask[rows, cols]
        order = np.random.default_rng(i).permutation(int(keep.sum()))
        rows, cols = rows[keep][order], cols[keep][order]
        with self._lock:
            sel = slice(None, None, self.thin)
            rows, cols = rows[sel], cols[sel]
            self._frames[i] = (rows, cols, {k: np.asarray(v)[rows, cols] for k, v in fields.items()})
            self._count += len(rows)
            while self._count > self.budget and any(len(v[0]) > 1 for v in self._frames.values()):
                self.thin *= 2
                self._frames = {k: (r[::2], c[::2], {n: a[::2] for n, a in f.items()})
                                for k, (r, c, f) in self._frames.items()}
                self._count = sum(len(v[0]) for v in self._frames.values())

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Rows, columns and fields kept of frame ``i`` (none if it added nothing)."""
        return self._frames.get(i, (np.zeros(0, int), np.zeros(0, int), {}))
