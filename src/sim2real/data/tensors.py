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

Training samples travel in compact dtypes (:func:`compact`) and are widened on the device
(:func:`widen`).
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


FP16_POINTS_MAX_MM = 1024.0
"""Surface points travel as fp16 while every coordinate is below this: fp16 keeps 11 significant
bits, so the rounding error is at most 2**-12 of the magnitude's power of two, 0.25 mm below
1024 mm, well inside the 1 mm occlusion tolerance (render/warp.py). Larger scenes keep fp32."""


def compact(sample: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A training sample in its transfer dtypes (shared memory, pinned copy, host-to-device):
    ``a_ref_*`` and ``normal_*`` fp16 (error <= 2**-11 on [-1, 1]), ``points_*`` fp16 under
    :data:`FP16_POINTS_MAX_MM`, ``object_id_*`` int16 (the G-buffer's own dtype), ``real*`` uint8
    (a crop of an 8-bit image mapped to [-1, 1] by ``/ 127.5 - 1``, so exactly invertible).
    Correspondences (``uv_*``, pixel positions up to the image width) stay fp32. A paper-size pair
    shrinks from 13.6 to 6.5 MiB. :func:`widen` restores the compute dtypes."""
    out = {}
    for k, v in sample.items():
        if k.startswith(("a_ref_", "normal_")):
            v = v.to(torch.float16)
        elif k.startswith("points_") and v.numel() and float(v.abs().max()) < FP16_POINTS_MAX_MM:
            v = v.to(torch.float16)
        elif k.startswith("object_id_"):
            v = v.to(torch.int16)
        elif k.startswith("real") and v.is_floating_point():
            v = torch.round((v + 1.0) * 127.5).to(torch.uint8)
        out[k] = v
    return out


def widen(batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The compute dtypes of a :func:`compact` batch, on whatever device it is (the trainer calls
    it after the host-to-device copy, so the copy moves the compact bytes): uint8 images ->
    float32 in [-1, 1] (bit-identical to the float crop), int16 -> int64, fp16 -> fp32. Other
    tensors and non-tensors pass unchanged."""
    out = {}
    for k, v in batch.items():
        if isinstance(v, torch.Tensor):
            if v.dtype == torch.uint8:
                v = v.to(torch.float32) / 127.5 - 1.0
            elif v.dtype == torch.int16:
                v = v.to(torch.int64)
            elif v.dtype == torch.float16:
                v = v.to(torch.float32)
        out[k] = v
    return out
