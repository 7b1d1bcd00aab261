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
(:func:`widen`). Their a_ref is not made by the loader worker: the sample carries what it takes
(:func:`view_inputs`: ``distance_{tag}``, ``camera_{tag}`` and ``albedo_{tag}`` instead of
``a_ref_{tag}``), and :func:`complete_on_device` renders it where the batch is (on a GPU, in
microseconds; in a worker it was a fifth of a paper-size sample's CPU time, benchmarks/bench_data.py).
"""

from __future__ import annotations

import numpy as np
import torch

from sim2real.render.gbuffer import GBuffer
from sim2real.render.reference import DISTANCE_CLAMP_MM, FALLOFF, reference_rendering


def view_tensors(gbuffers: list[GBuffer], tag: str) -> dict[str, torch.Tensor]:
    """Stack the views ``gbuffers`` (all of one size) into the tensors of the module table."""
    a_ref = np.stack([reference_rendering(g).transpose(2, 0, 1) for g in gbuffers]) * np.float32(2.0) - np.float32(1.0)
    return {
        f"a_ref_{tag}": torch.from_numpy(a_ref.astype(np.float32, copy=False)),
        f"object_id_{tag}": torch.from_numpy(np.stack([g.object_id.astype(np.int64) for g in gbuffers])),
        f"points_{tag}": torch.from_numpy(np.stack([np.asarray(g.points, dtype=np.float32) for g in gbuffers])),
        f"normal_{tag}": torch.from_numpy(np.stack([np.asarray(g.normal, dtype=np.float32) for g in gbuffers])),
    }


def view_inputs(gbuffers: list[GBuffer], tag: str, max_objects: int) -> dict[str, torch.Tensor]:
    """The view tensors without a_ref, and what :func:`complete_on_device` renders it from:
    ``distance_{tag}`` (B, H, W) f32 (mm), ``camera_{tag}`` (B, 3) f32 camera position (mm) and
    ``albedo_{tag}`` (B, max_objects, 3) f32, each object's a_ref colour from the view's class
    table (zero past the scene's objects)."""
    albedo = np.zeros((len(gbuffers), max_objects, 3), np.float32)
    for b, g in enumerate(gbuffers):
        albedo[b, : len(g.classes)] = g.class_table.albedo(g.classes)
    return {
        f"object_id_{tag}": torch.from_numpy(np.stack([g.object_id.astype(np.int64) for g in gbuffers])),
        f"points_{tag}": torch.from_numpy(np.stack([np.asarray(g.points, dtype=np.float32) for g in gbuffers])),
        f"normal_{tag}": torch.from_numpy(np.stack([np.asarray(g.normal, dtype=np.float32) for g in gbuffers])),
        f"distance_{tag}": torch.from_numpy(np.stack([np.asarray(g.distance, dtype=np.float32) for g in gbuffers])),
        f"camera_{tag}": torch.from_numpy(np.stack([g.camera.position.astype(np.float32) for g in gbuffers])),
        f"albedo_{tag}": torch.from_numpy(albedo),
    }


def reference_on_device(object_id: torch.Tensor, normal: torch.Tensor, points: torch.Tensor, distance: torch.Tensor,
                        camera: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """a_ref (B, 3, H, W) in [-1, 1] on the tensors' device: the formula of
    :func:`sim2real.render.reference.reference_rendering` (paper Eq. 2), in torch. Inputs as
    :func:`view_inputs` gives them (widened)."""
    dev = points.device
    mask = object_id >= 0
    b_idx = torch.arange(object_id.shape[0], device=dev)[:, None, None]
    colour = albedo.float()[b_idx, object_id.clamp(min=0)]  # (B, H, W, 3): each pixel's object colour
    to_cam = camera[:, None, None, :] - points
    view_dir = to_cam / to_cam.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    diffuse = (normal * view_dir).sum(-1).clamp(0.0, 1.0)
    d = distance.clamp(max=DISTANCE_CLAMP_MM)
    a, b, c = FALLOFF
    shade = (0.9 * diffuse + 0.1) / (a * d * d + b * d + c)
    out = (colour * shade[..., None]).clamp(0.0, 1.0) * mask[..., None]
    return out.permute(0, 3, 1, 2) * 2.0 - 1.0


def complete_on_device(batch: dict) -> dict:
    """Render ``a_ref_{tag}`` for every view of a widened batch that carries its
    :func:`view_inputs` instead, and drop those inputs (the methods see the keys of the module
    table)."""
    out = dict(batch)
    for key in [k for k in batch if k.startswith("distance_")]:
        tag = key[len("distance_"):]
        out[f"a_ref_{tag}"] = reference_on_device(out[f"object_id_{tag}"], out[f"normal_{tag}"], out[f"points_{tag}"],
                                                  out.pop(f"distance_{tag}"), out.pop(f"camera_{tag}"),
                                                  out.pop(f"albedo_{tag}"))
    return out


FP16_POINTS_MAX_MM = 1024.0
"""Surface points travel as fp16 while every coordinate is below this: fp16 keeps 11 significant
bits, so the rounding error is at most 2**-12 of the magnitude's power of two, 0.25 mm below
1024 mm, well inside the 1 mm occlusion tolerance (render/warp.py). Larger scenes keep fp32."""


def compact(sample: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A training sample in its transfer dtypes (shared memory, pinned copy, host-to-device):
    ``a_ref_*`` and ``normal_*`` fp16 (error <= 2**-11 on [-1, 1]), ``distance_*`` fp16 (2**-11
    relative: 0.05 mm at 100 mm, where a_ref's falloff stops), ``points_*`` fp16 under
    :data:`FP16_POINTS_MAX_MM`, ``object_id_*`` int16 (the G-buffer's own dtype), ``real*`` uint8
    (a crop of an 8-bit image mapped to [-1, 1] by ``/ 127.5 - 1``, so exactly invertible).
    Correspondences (``uv_*``, pixel positions up to the image width) stay fp32. A paper-size pair
    shrinks from 13.6 to 6.5 MiB. :func:`widen` restores the compute dtypes."""
    out = {}
    for k, v in sample.items():
        if k.startswith(("a_ref_", "normal_", "distance_")):
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
