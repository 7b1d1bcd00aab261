"""G-buffers -> the tensors of one batch (training samples and inference share this)."""

from __future__ import annotations

import numpy as np
import torch


def view_tensors(gbuffers, tag: str) -> dict[str, torch.Tensor]:
    """Stacked view tensors of ``gbuffers`` (one size), keys suffixed ``_{tag}``:

    ``a_ref`` (B, 3, H, W) float32 reference rendering in [-1, 1]; ``object_id`` (B, H, W) int64
    (-1 background); ``points`` (B, H, W, 3) float32 world mm; ``normal`` (B, H, W, 3) float32."""
    from sim2real.render.reference import reference_rendering

    a_ref = np.stack([reference_rendering(g).transpose(2, 0, 1) for g in gbuffers]).astype(np.float32) * 2.0 - 1.0
    return {
        f"a_ref_{tag}": torch.from_numpy(a_ref),
        f"object_id_{tag}": torch.from_numpy(np.stack([g.object_id.astype(np.int64) for g in gbuffers])),
        f"points_{tag}": torch.from_numpy(np.stack([np.asarray(g.points, dtype=np.float32) for g in gbuffers])),
        f"normal_{tag}": torch.from_numpy(np.stack([np.asarray(g.normal, dtype=np.float32) for g in gbuffers])),
    }
