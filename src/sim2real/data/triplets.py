"""Training samples of the video methods: consecutive frames in both domains.

Kind ``triplets`` (:func:`sim2real.data.datasets.make_dataset`): each step takes one scene,
ray-casts 3 frames along a short random linear camera path
(:func:`sim2real.scene.trajectory.linear_path`, ``data.path_step_mm`` per frame; paper
supplementary: "random, linear trajectories comparable to the motion in real sequences"), and
3 consecutive real frames of a random real sequence (:class:`sim2real.data.real.RealSequences`,
one random resized crop for all three). A views folder in ``--scenes`` is ray-cast from its
scene folder: cached views are not paths.

Sample keys (the DataLoader adds the batch dimension; compact dtypes in transit, as for view
pairs), for frames ``t`` = 0, 1, 2:

=====================  =============  =====================================================
key                    shape          meaning
=====================  =============  =====================================================
``step``, ``scene``    ()             as for view pairs (data/pairs.py)
``a_ref_t`` ...        (3, H, W) ...  view tensors of frame t (data/tensors.py)
``uv_10``, ``uv_21``   (H, W, 2)      position of frame t's pixels in frame t-1 (ground-truth
                                      flow as a backward warp: w(x_{t-1}) samples there)
``visible_10`` ...     (H, W) bool    frame t's pixel is visible in frame t-1
``real_t``             (3, H, W)      consecutive real frames in [-1, 1]
=====================  =============  =====================================================
"""

from __future__ import annotations

import numpy as np
import torch

from sim2real.data.pairs import TrainPairs, sample_transfer_bytes
from sim2real.data.real import RealSequences
from sim2real.data.tensors import compact
from sim2real.render.warp import correspondences
from sim2real.scene.trajectory import linear_path

FRAMES = 3


class TrainTriplets(TrainPairs):
    """Step-indexed triplets (see the module docstring); the real folder must hold sequences."""

    def __init__(self, sources, real, cfg, seed: int, rank: int = 0):
        super().__init__(sources, real, cfg, seed, rank)
        self.sequences = RealSequences(real.folder, FRAMES)

    def transfer_bytes(self) -> int:
        """Upper bound of one sample's bytes in transit: three views, two correspondences, three
        real crops (see :meth:`TrainPairs.transfer_bytes`)."""
        return sample_transfer_bytes(self.cfg.height, self.cfg.width, views=FRAMES, crops=FRAMES)

    def __getitem__(self, step: int) -> dict[str, torch.Tensor]:
        rng = self.rng(step)
        k = int(rng.integers(0, len(self.sources)))
        caster = self._caster(self.sources[k])
        c = self.cfg
        cams = linear_path(caster, FRAMES, c.height, c.width, c.fov_x_deg, c.path_step_mm, rng, K=self.K)
        frames = [caster.render(cam) for cam in cams]
        out = {"step": torch.tensor(int(step)), "scene": torch.tensor(k)}
        for t, g in enumerate(frames):
            out.update(self.view_keys(g, str(t)))
            if t:
                uv, visible = correspondences(g, frames[t - 1])
                out[f"uv_{t}{t - 1}"] = torch.from_numpy(uv)
                out[f"visible_{t}{t - 1}"] = torch.from_numpy(visible)
        for t, real in enumerate(self.sequences.sample(rng, c.height, c.width, c.real_scale_min, c.real_scale_max)):
            out[f"real_{t}"] = torch.from_numpy(np.ascontiguousarray(real))
        return compact(out)
