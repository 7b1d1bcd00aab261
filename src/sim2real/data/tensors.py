"""G-buffers -> the network-side tensors of one view per sample, shared by training and inference.

=====================  ==================  ===========================================
key                    shape, dtype        meaning
=====================  ==================  ===========================================
``a_ref_{tag}``        (B, 3, H, W) f32    reference rendering mapped to [-1, 1]
``object_id_{tag}``    (B, H, W) int64     object ids, -1 background
``points_{tag}``       (B, H, W, 3) f32    world surface points (mm)
``normal_{tag}``       (B, H, W, 3) f32    world unit normals
=====================  ==================  ===========================================

``tag`` is the view's name in a batch (``i`` or ``j``). The tensors are on the CPU.
"""

from __future__ import annotations

import numpy as np
import torch

from sim2real.render.gbuffer import GBuffer
from sim2real.render.reference import reference_rendering


def view_tensors(gbuffers: list[GBuffer], tag: str) -> dict[str, torch.Tensor]:
    """Stack the views ``gbuffers`` (all of one size) into the tensors of the module table."""
    a_ref = np.stack([reference_rendering(g).transpose(2, 0, 1) for g in gbuffers]) * np.float32(2.0) - np.float32(1.0)
    return {
        f"a_ref_{tag}": torch.from_numpy(a_ref.astype(np.float32, copy=False)),
        f"object_id_{tag}": torch.from_numpy(np.stack([g.object_id.astype(np.int64) for g in gbuffers])),
        f"points_{tag}": torch.from_numpy(np.stack([np.asarray(g.points, dtype=np.float32) for g in gbuffers])),
        f"normal_{tag}": torch.from_numpy(np.stack([np.asarray(g.normal, dtype=np.float32) for g in gbuffers])),
    }
