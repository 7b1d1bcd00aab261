"""The training samples of the image methods: views of one simulated scene (two, i and j, or one,
i) and one real image per step.

A method declares the kind of sample it trains on (:func:`sim2real.data.datasets.make_dataset`):
``view_pairs`` (i, j and their correspondences) or ``views`` (i alone: the keys ``*_j``,
``uv_ij`` and ``visible_ij`` are absent, and no view j is ray-cast). Views come from
:class:`~sim2real.data.sources.SceneSource`: cached G-buffers of a views folder, the scene's view
pool (data/viewpool.py: memory-mapped, read without a copy per worker), or fresh random poses
ray-cast in the loader worker.

The dataset is map-style and indexed by the **training step**: everything random in sample ``s``
comes from ``numpy.random.default_rng((seed, rank, s))``. The data stream therefore depends only
on (seed, rank, step), not on the number of workers or on where a run was resumed, and a
checkpoint needs no loader state.

Sample keys (one step; the DataLoader adds the batch dimension). Samples travel in the compact
dtypes of :func:`sim2real.data.tensors.compact` and carry what a_ref is rendered from
(:func:`sim2real.data.tensors.view_inputs`) instead of a_ref; the trainer widens them on its
device and renders a_ref there (:func:`~sim2real.data.tensors.widen`,
:func:`~sim2real.data.tensors.complete_on_device`). The table gives the completed form:

=================  =============  =========================================================
key                shape          meaning
=================  =============  =========================================================
``step``           ()             training step the sample belongs to
``scene``          ()             index into the dataset's ``sources`` (and the textures)
``a_ref_i/_j``     (3, H, W)      reference rendering in [-1, 1]
``object_id_i/_j`` (H, W) int64   object ids, -1 background
``points_i/_j``    (H, W, 3)      world surface points (mm)
``normal_i/_j``    (H, W, 3)      world unit normals
``uv_ij``          (H, W, 2)      position of view i's pixels in view j (pixel units)
``visible_ij``     (H, W) bool    i's pixel is visible in j (render.warp.correspondences)
``real``           (3, H, W)      random resized crop of a real image in [-1, 1]
=================  =============  =========================================================

The texture projection is not done here: it needs gradients and runs in the training process.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections import OrderedDict
from pathlib import Path

import numpy as np
import torch

from sim2real.config import DataConfig
from sim2real.data.real import RealImages
from sim2real.data.sources import SceneSource
from sim2real.data.tensors import compact, view_inputs, view_tensors
from sim2real.render.gbuffer import GBuffer
from sim2real.render.raycast import RayCaster
from sim2real.render.warp import correspondences
from sim2real.scene.scene import Scene
from sim2real.scene.camera import view_intrinsics
from sim2real.scene.trajectory import MAX_BACKGROUND, sample_poses

PAIR_TRIES = 10
OVERLAP_SAMPLES = 8192
"""Pixels of view i (at least) on which a pair's overlap is judged (:func:`overlap_grid`)."""
_CACHE_VIEWS = 64  # decoded G-buffers kept per worker


VIEW_BYTES_PER_PIXEL = 26
"""One view in transit (:func:`~sim2real.data.tensors.compact`), at most: normals fp16 (6),
object ids int16 (2), points fp32 at most (12), and a_ref fp16 (6) or the distance fp16 (2)."""


def sample_transfer_bytes(height: int, width: int, views: int = 2, crops: int = 1) -> int:
    """Upper bound of one training sample's bytes in transit (shared memory, pinned copy): its
    ``views``, the correspondences between consecutive views (uv fp32 8, visible 1 per pixel) and
    its ``crops`` uint8 real crops (3)."""
    per_px = VIEW_BYTES_PER_PIXEL * views + 9 * (views - 1) + 3 * crops
    return per_px * height * width + 4096


def overlap_grid(g: GBuffer) -> GBuffer:
    """View ``g`` on every s-th pixel of every s-th row, s the largest stride that keeps
    :data:`OVERLAP_SAMPLES` pixels (1 up to 64x128, 4 at 256x512): what the overlap of a pair is
    judged on. The share of a 16x sparser grid that j sees differs from the full view's by about
    0.005 (the standard error of a fraction over 8,192 pixels), while the correspondences of a
    redrawn j cost a sixteenth (18 ms of a 256x512 pair, benchmarks/bench_data.py)."""
    s = max(1, int(np.sqrt(g.height * g.width / OVERLAP_SAMPLES)))
    if s == 1:
        return g
    return dataclasses.replace(g, depth=g.depth[::s, ::s], distance=g.distance[::s, ::s], normal=g.normal[::s, ::s],
                               object_id=g.object_id[::s, ::s], points=g.points[::s, ::s])


class TrainPairs(torch.utils.data.Dataset):
    """Map-style dataset whose index is the training step (see module docstring); ``pairs=False``
    gives single views."""

    def __init__(self, sources: list[SceneSource], real: RealImages, cfg: DataConfig, seed: int, rank: int = 0,
                 pairs: bool = True):
        self.pairs = bool(pairs)
        self.sources = sources
        self.real = real
        self.cfg = cfg
        self.K = view_intrinsics(cfg.width, cfg.height, cfg.fov_x_deg, cfg.intrinsics)
        """The intrinsics of fresh random views (``data.intrinsics`` or ``data.fov_x_deg``)."""
        self.seed = int(seed)
        self.rank = int(rank)
        self._casters: dict = {}
        self._views: OrderedDict = OrderedDict()
        self._pid = os.getpid()
        self.max_objects = max(len(src.classes) for src in sources)
        self.a_ref_in_worker = False
        """Render a_ref in the loader worker (a CPU run: no device to hand it to, and the worker
        has time while the CPU step runs) instead of shipping what it is made of."""

    def transfer_bytes(self) -> int:
        """Upper bound of one sample's bytes in transit (:func:`sample_transfer_bytes`)."""
        return sample_transfer_bytes(self.cfg.height, self.cfg.width, views=2 if self.pairs else 1)

    def view_keys(self, g: GBuffer, tag: str) -> dict[str, torch.Tensor]:
        """One view's tensors: with a_ref (:attr:`a_ref_in_worker`) or with its inputs."""
        if self.a_ref_in_worker:
            return {k: v[0] for k, v in view_tensors([g], tag).items()}
        return {k: v[0] for k, v in view_inputs([g], tag, self.max_objects).items()}

    def __len__(self) -> int:  # indexed by step; the sampler decides the range
        return 2**62

    def __getstate__(self):  # Embree scenes and caches stay out of worker pickles
        state = self.__dict__.copy()
        state["_casters"], state["_views"] = {}, OrderedDict()
        return state

    def rng(self, step: int) -> np.random.Generator:
        return np.random.default_rng((self.seed, self.rank, int(step)))

    def __getitem__(self, step: int) -> dict[str, torch.Tensor]:
        rng = self.rng(step)
        k = int(rng.integers(0, len(self.sources)))
        src = self.sources[k]
        ki, gi = self._view(src, rng)
        views = [("i", gi)]
        out = {"step": torch.tensor(int(step)), "scene": torch.tensor(k)}
        if self.pairs:
            # A j that sees too little of view i is redrawn (not the pair: half the ray casting
            # of a redraw). The overlap is judged on a grid of view i's pixels
            # (:func:`overlap_grid`), the correspondences made once, for the j kept.
            grid = overlap_grid(gi)
            best = None
            for _ in range(PAIR_TRIES):
                _, gj = self._view(src, rng, avoid=ki)
                overlap = float(correspondences(grid, gj)[1].mean())
                if best is None or overlap > best[0]:
                    best = (overlap, gj)
                if overlap >= self.cfg.min_overlap:
                    break
            gj = best[1]
            uv, visible = correspondences(gi, gj)
            views.append(("j", gj))
            out["uv_ij"] = torch.from_numpy(uv)
            out["visible_ij"] = torch.from_numpy(visible)
        c = self.cfg
        real = self.real.sample(rng, c.height, c.width, c.real_scale_min, c.real_scale_max)
        for tag, g in views:
            out.update(self.view_keys(g, tag))
        out["real"] = torch.from_numpy(np.ascontiguousarray(real))
        return compact(out)

    # --- views ---------------------------------------------------------------------------------

    def _view(self, src: SceneSource, rng: np.random.Generator, avoid: int | None = None):
        """``(index, G-buffer)``: a view of ``src``'s views folder or view pool other than number
        ``avoid``, or a fresh random pose ray-cast now (index None)."""
        n = src.finite
        if n:
            k = int(rng.integers(0, n if avoid is None else n - 1))
            if avoid is not None and k >= avoid:
                k += 1
            return k, (self._cached_view(src.view_files[k]) if src.cached else src.pool.view(k))
        caster = self._caster(src)
        c = self.cfg
        before = caster.skipped_background
        cam = sample_poses(caster, 1, c.height, c.width, c.fov_x_deg, seed=int(rng.integers(0, 2**31)), K=self.K)[0]
        after = caster.skipped_background
        if after > before and any(before < m <= after for m in (1, 10, 100, 1000, 10000)):  # a few lines, not one per view
            print(f"scene '{src.name}': {after} random views skipped so far in this loader process "
                  f"(more than {MAX_BACKGROUND:.0%} background: rays escape through open meshes)", file=sys.stderr)
        return None, caster.render(cam)

    def _caster(self, src: SceneSource):
        if os.getpid() != self._pid:  # a forked worker must not reuse the parent's Embree objects
            self._casters, self._pid = {}, os.getpid()
        if src.name not in self._casters:
            self._casters[src.name] = RayCaster(Scene.load(src.scene_dir))
        return self._casters[src.name]

    def _cached_view(self, path: Path):
        g = self._views.get(path)
        if g is None:
            g = GBuffer.load(path)
            self._views[path] = g
            if len(self._views) > _CACHE_VIEWS:
                self._views.popitem(last=False)
        else:
            self._views.move_to_end(path)
        return g
