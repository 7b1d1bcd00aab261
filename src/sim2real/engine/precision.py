"""Numeric format per device: bf16 autocast with channels-last images and weights on CUDA,
fp32 in the default layout on the CPU. Training and inference both ask here; inference may also
run bf16 on the CPU on request (:func:`inference_bf16`)."""

from __future__ import annotations

import contextlib
import platform

import torch


def mixed_precision(device: torch.device) -> bool:
    """Whether ``device`` runs bf16 autocast and channels-last tensors: CUDA only. Tests switch
    it on for the CPU to exercise that path (CPU autocast has the same bf16 semantics)."""
    return device.type == "cuda"


def autocast(device: torch.device, enabled: bool):
    """bf16 autocast on ``device`` when ``enabled`` (no loss scaling is needed for bf16)."""
    if enabled:
        return torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext()


INFERENCE_PRECISIONS = ("auto", "fp32", "bf16")


def cpu_has_bf16(machine: str | None = None) -> bool:
    """Whether this CPU (``machine``: its architecture, default :func:`platform.machine`) has bf16
    instructions: AVX512-BF16 or AMX tiles on x86; the Armv8.6 BF16 extension on 64-bit Arm, as
    torch's own oneDNN dispatch asks it there. Without them oneDNN emulates bf16
    (:func:`emulated_bf16`). Any other architecture, or a torch without these probes: no."""
    machine = (machine or platform.machine()).lower()
    try:
        if machine in ("x86_64", "amd64", "i386", "i686"):
            return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
        if machine in ("aarch64", "arm64"):
            # on x86 this probe says AVX-512 (which emulates bf16), on 64-bit Arm the BF16 extension
            return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch without these probes (or built without oneDNN)
        pass
    return False


def emulated_bf16(device: torch.device, bf16: bool) -> bool:
    """Whether bf16 autocast (``bf16``) on ``device`` is emulated: on a CPU without bf16
    instructions. Measured there (a 2-core AMD EPYC without AVX-512, docs/gpu.md): a matrix
    product at 1.3 GFLOP/s in bf16 against 180 in fp32, the tiny preset's networks 21x slower."""
    return bf16 and device.type == "cpu" and not cpu_has_bf16()


def inference_bf16(device: torch.device, choice: str, run_amp: bool) -> bool:
    """Whether translation runs under bf16 autocast. ``choice``: 'auto' -> the run's ``amp`` on
    CUDA and fp32 on the CPU (exact, the same frames on every CPU); 'bf16' -> bf16 on any device
    (on a CPU with bf16 instructions the networks ran 1.3-1.6x faster, frames within a few
    8-bit levels of fp32: docs/gpu.md); 'fp32' -> never. Channels-last stays CUDA-only: on the
    CPU it made the networks slower (docs/gpu.md, small preset at 256x512: fp32 2.07 -> 1.99
    frames/s, bf16 3.55 -> 3.35)."""
    if choice not in INFERENCE_PRECISIONS:
        raise ValueError(f"precision must be one of {INFERENCE_PRECISIONS}, got {choice!r}")
    if choice == "auto":
        return mixed_precision(device) and bool(run_amp)
    return choice == "bf16"
