"""Training samples: views of one simulated scene (two, i and j, or one, i) and one real image per step.

A method declares the kind of sample it trains on (:func:`make_dataset`): ``view_pairs`` (i, j
and their correspondences) or ``views`` (i alone: the keys ``*_j``, ``uv_ij`` and ``visible_ij``
are absent, and no view j is ray-cast).

``--scenes`` entries are either scene folders (``scene.json``) or views folders
(``views.json`` naming their ``scene_dir``):

* a **views folder** gives cached G-buffers; each step draws two different views of it;
* a **bare scene folder** (no cache) gives unlimited fresh random views: each step ray-casts
  two new random poses (:func:`sim2real.scene.trajectory.sample_poses`) in the loader worker.

Several views folders of the same scene are merged. The dataset is map-style and indexed by
the **training step**: everything random in sample ``s`` comes from
``numpy.random.default_rng((seed, rank, s))``. The data stream therefore depends only on
(seed, rank, step), not on the number of workers or on where a run was resumed, and a
checkpoint needs no loader state.

Sample keys (one step; the DataLoader adds the batch dimension):

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

import os
import sys
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from sim2real.config import DataConfig
from sim2real.data.real import RealImages
from sim2real.errors import UserError
from sim2real.scene.classes import ClassTable

PAIR_TRIES = 10
_CACHE_VIEWS = 64  # decoded G-buffers kept per worker


@dataclass
class SceneSource:
    """One scene of the training set and where its views come from."""

    name: str
    scene_dir: Path
    classes: tuple[str, ...]
    bounds: np.ndarray
    """(O, 2, 3) object bounding boxes (mm): the texture planes span them."""
    view_files: list[Path] | None = None
    """Cached G-buffers, or None to ray-cast fresh random views."""
    class_table: ClassTable | None = None
    """Label ids and a_ref colours of the scene's classes (None: the defaults)."""

    @property
    def cached(self) -> bool:
        return self.view_files is not None

    def to_json(self) -> dict:
        table = self.class_table if self.class_table is not None else ClassTable.migrate(self.classes)
        return {"name": self.name, "scene_dir": str(self.scene_dir),
                "views": None if self.view_files is None else [str(p) for p in self.view_files],
                "classes": list(self.classes), "class_table": table.to_json()}


def resolve_scenes(paths: list[str | os.PathLike], height: int, width: int) -> list[SceneSource]:
    """Turn ``--scenes`` entries into sources (one per scene, in order of first mention)."""
    from sim2real.data.views import MANIFEST, list_views
    from sim2real.render.gbuffer import GBuffer
    from sim2real.scene.scene import Scene

    if not paths:
        raise UserError("no simulated scenes given (--scenes DIR...)")
    by_name: dict[str, SceneSource] = {}
    for raw in paths:
        path = Path(raw)
        if (path / MANIFEST).is_file():
            manifest, files = list_views(path)
            if not files:
                raise UserError(f"views folder {path} holds no views")
            scene_dir = Path(manifest.get("scene_dir", ""))
            if not (scene_dir / "scene.json").is_file():
                raise UserError(f"views folder {path} names scene_dir {scene_dir}, which is not a scene folder; "
                                f"the scene is needed for its object bounding boxes")
            scene = Scene.load(scene_dir)
            first = GBuffer.load(files[0])
            if (first.height, first.width) != (height, width):
                raise UserError(f"views in {path} are {first.height}x{first.width} but training uses {height}x{width} "
                                f"(render them at that size, or set data.height/data.width)")
            if tuple(first.classes) != scene.classes:
                raise UserError(f"views in {path} do not match the objects of scene '{scene.name}' in {scene_dir}")
            if first.class_table != scene.class_table:
                raise UserError(f"views in {path} were rendered with other class colours than scene '{scene.name}' "
                                f"in {scene_dir} has now; render them again")
            src = by_name.get(scene.name)
            if src is not None and not src.cached:
                raise UserError(f"scene '{scene.name}' is given both as a scene folder and as views folder {path}; give one")
            if src is None:
                by_name[scene.name] = SceneSource(scene.name, scene_dir.resolve(), scene.classes, scene.bounds(), list(files),
                                                 scene.class_table)
            else:
                src.view_files.extend(files)
        elif (path / "scene.json").is_file():
            scene = Scene.load(path)
            if scene.name in by_name:
                raise UserError(f"scene '{scene.name}' is given twice (second time: {path})")
            by_name[scene.name] = SceneSource(scene.name, path.resolve(), scene.classes, scene.bounds(), None,
                                            scene.class_table)
        elif path.is_dir():
            raise UserError(f"{path} is neither a scene folder (scene.json) nor a finished views folder ({MANIFEST})")
        else:
            raise UserError(f"scene or views folder {path} does not exist")
    for src in by_name.values():
        if src.cached and len(src.view_files) < 2:
            raise UserError(f"scene '{src.name}' has only {len(src.view_files)} cached view; "
                            f"view consistency needs at least 2 views per scene")
    return list(by_name.values())


class TrainPairs(torch.utils.data.Dataset):
    """Map-style dataset whose index is the training step (see module docstring); ``pairs=False``
    gives single views."""

    def __init__(self, sources: list[SceneSource], real: RealImages, cfg: DataConfig, seed: int, rank: int = 0,
                 pairs: bool = True):
        self.pairs = bool(pairs)
        self.sources = sources
        self.real = real
        self.cfg = cfg
        self.seed = int(seed)
        self.rank = int(rank)
        self._casters: dict = {}
        self._views: OrderedDict = OrderedDict()
        self._pid = os.getpid()

    def __len__(self) -> int:  # indexed by step; the sampler decides the range
        return 2**62

    def __getstate__(self):  # Embree scenes and caches stay out of worker pickles
        state = self.__dict__.copy()
        state["_casters"], state["_views"] = {}, OrderedDict()
        return state

    def rng(self, step: int) -> np.random.Generator:
        return np.random.default_rng((self.seed, self.rank, int(step)))

    def __getitem__(self, step: int) -> dict[str, torch.Tensor]:
        from sim2real.data.tensors import view_tensors
        from sim2real.render.warp import correspondences

        rng = self.rng(step)
        k = int(rng.integers(0, len(self.sources)))
        src = self.sources[k]
        ki, gi = self._view(src, rng)
        views = [("i", gi)]
        out = {"step": torch.tensor(int(step)), "scene": torch.tensor(k)}
        if self.pairs:
            # A j that sees too little of view i is redrawn (not the pair: half the ray casting
            # of a redraw).
            best = None
            for _ in range(PAIR_TRIES):
                _, gj = self._view(src, rng, avoid=ki)
                uv, visible = correspondences(gi, gj)
                overlap = float(visible.mean())
                if best is None or overlap > best[0]:
                    best = (overlap, gj, uv, visible)
                if overlap >= self.cfg.min_overlap:
                    break
            _, gj, uv, visible = best
            views.append(("j", gj))
            out["uv_ij"] = torch.from_numpy(uv)
            out["visible_ij"] = torch.from_numpy(visible)
        c = self.cfg
        real = self.real.sample(rng, c.height, c.width, c.real_scale_min, c.real_scale_max)
        for tag, g in views:
            out.update({key: v[0] for key, v in view_tensors([g], tag).items()})
        out["real"] = torch.from_numpy(np.ascontiguousarray(real))
        return out

    # --- views ---------------------------------------------------------------------------------

    def _view(self, src: SceneSource, rng: np.random.Generator, avoid: int | None = None):
        """``(index, G-buffer)``: a cached view of ``src`` other than number ``avoid`` (index into
        its files), or a fresh random pose ray-cast now (index None)."""
        if src.cached:
            n = len(src.view_files)
            k = int(rng.integers(0, n if avoid is None else n - 1))
            if avoid is not None and k >= avoid:
                k += 1
            return k, self._cached_view(src.view_files[k])
        from sim2real.scene.trajectory import sample_poses

        caster = self._caster(src)
        c = self.cfg
        before = caster.skipped_background
        cam = sample_poses(caster, 1, c.height, c.width, c.fov_x_deg, seed=int(rng.integers(0, 2**31)))[0]
        after = caster.skipped_background
        if after > before and any(before < m <= after for m in (1, 10, 100, 1000, 10000)):  # a few lines, not one per view
            from sim2real.scene.trajectory import MAX_BACKGROUND

            print(f"scene '{src.name}': {after} random views skipped so far in this loader process "
                  f"(more than {MAX_BACKGROUND:.0%} background: rays escape through open meshes)", file=sys.stderr)
        return None, caster.render(cam)

    def _caster(self, src: SceneSource):
        if os.getpid() != self._pid:  # a forked worker must not reuse the parent's Embree objects
            self._casters, self._pid = {}, os.getpid()
        if src.name not in self._casters:
            from sim2real.render.raycast import RayCaster
            from sim2real.scene.scene import Scene

            self._casters[src.name] = RayCaster(Scene.load(src.scene_dir))
        return self._casters[src.name]

    def _cached_view(self, path: Path):
        from sim2real.render.gbuffer import GBuffer

        g = self._views.get(path)
        if g is None:
            g = GBuffer.load(path)
            self._views[path] = g
            if len(self._views) > _CACHE_VIEWS:
                self._views.popitem(last=False)
        else:
            self._views.move_to_end(path)
        return g


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
        from sim2real.data.triplets import TrainTriplets

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
