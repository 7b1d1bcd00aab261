"""bf16 autocast on the CPU (the CUDA recipe's numerics): every method preset and structure term
takes a finite training step close to the fp32 one, and the structure and SSIM terms compute in
fp32 under autocast."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch.utils.data import default_collate
from train_data import tiny_config

from sim2real.engine import precision
from sim2real.engine.trainer import Trainer
from sim2real.losses.ssim import ms_ssim_loss
from sim2real.losses.structure import edge_recall_loss
from sim2real.methods import get_method
from sim2real.presets import METHOD_PRESETS

pytestmark = pytest.mark.usefixtures("one_torch_thread")

# Loss terms of one bf16 step against fp32: bf16 keeps 8 significant bits (relative rounding
# 2**-9 per operation); through a few dozen layers the terms of the tiny nets moved by at most
# 1.6 % (measured over the presets below), so 5 % relative or 0.02 absolute (near-zero terms).
REL, ABS = 0.05, 0.02


def _images(seed: int, shape=(2, 3, 48, 80)) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    a = torch.nn.functional.avg_pool2d(torch.rand(shape, generator=g) * 2 - 1, 5, 1, 2)  # soft edges
    return a, (a + 0.1 * torch.randn(shape, generator=g)).clamp(-1, 1)


def test_edge_recall_is_fp32_under_autocast():
    """Under bf16 autocast the term equals its fp32 value (its convolutions would otherwise run
    in bf16, where the 0.02 grey contrast is a few rounding steps), also for a bf16 network output."""
    a, x = _images(0)
    want = edge_recall_loss(a, x)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = edge_recall_loss(a, x)
        got_bf16_input = edge_recall_loss(a, x.to(torch.bfloat16))
    assert got.dtype == torch.float32
    assert torch.equal(got, want)
    assert got_bf16_input.item() == pytest.approx(edge_recall_loss(a, x.to(torch.bfloat16).float()).item(), abs=1e-7)


def test_ms_ssim_is_fp32_under_autocast():
    a, x = _images(1, (2, 3, 64, 96))
    want = ms_ssim_loss(a, x, win=3, scales=3)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = ms_ssim_loss(a, x, win=3, scales=3)
    assert got.dtype == torch.float32 and torch.equal(got, want)
    assert 0.01 < want.item() < 1  # a real comparison, not the degenerate constant 1 of bf16 variances


CASES = [(name, "ms_ssim") for name in sorted(METHOD_PRESETS)] + [("ours", "edges")]


@pytest.mark.parametrize("name,structure", CASES)
def test_bf16_step_is_finite_and_close_to_fp32(name, structure, request, tmp_path, monkeypatch):
    cfg = tiny_config(name, **{"loss__ab_structure": structure})
    if hasattr(cfg.method, "vc_start"):
        cfg.method.vc_start = 0  # the view-consistency term in the step too
    video = get_method(cfg).data == "triplets"
    scenes, real = request.getfixturevalue("video_train_inputs" if video else "train_inputs")
    fp32 = Trainer(cfg, [scenes], real, tmp_path / "fp32", progress=False)
    monkeypatch.setattr(precision, "mixed_precision", lambda device: True)
    bf16 = Trainer(cfg, [scenes], real, tmp_path / "bf16", progress=False)
    try:
        assert bf16.amp and not fp32.amp
        batch = default_collate([fp32.dataset[0]])
        torch.manual_seed(1)  # a stochastic method (styles, noise) draws the same in both steps
        l32 = fp32.train_step(fp32._to_device(batch), 0)
        torch.manual_seed(1)
        l16 = bf16.train_step(bf16._to_device(batch), 0)
    finally:
        fp32.close()
        bf16.close()
    assert l16.keys() == l32.keys()
    for k in l32:
        assert torch.isfinite(l16[k]) and l16[k].dtype == torch.float32, k
        assert l16[k].item() == pytest.approx(l32[k].item(), rel=REL, abs=ABS), (k, l16[k].item(), l32[k].item())


def test_inference_precision_choices():
    """'auto' follows the run on CUDA and is fp32 on the CPU; an explicit choice holds on every
    device; the CLI offers exactly the choices the engine knows."""
    from sim2real.cli.args import PRECISIONS

    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert precision.INFERENCE_PRECISIONS == PRECISIONS
    assert precision.inference_bf16(cuda, "auto", True) and not precision.inference_bf16(cuda, "auto", False)
    assert not precision.inference_bf16(cpu, "auto", True)
    assert precision.inference_bf16(cpu, "bf16", False) and precision.inference_bf16(cuda, "bf16", False)
    assert not precision.inference_bf16(cuda, "fp32", True)
    with pytest.raises(ValueError, match="fp16"):
        precision.inference_bf16(cpu, "fp16", True)


def test_emulated_bf16_is_bf16_on_a_cpu_without_its_instructions(monkeypatch):
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    for has in (False, True):
        monkeypatch.setattr(precision, "cpu_has_bf16", lambda: has)
        assert precision.emulated_bf16(cpu, True) is (not has)
        assert not precision.emulated_bf16(cpu, False) and not precision.emulated_bf16(cuda, True)



@pytest.mark.skipif(not Path("/proc/cpuinfo").is_file(), reason="needs /proc/cpuinfo (Linux)")
def test_cpu_bf16_probe_agrees_with_the_kernel():
    # x86 lists its extensions under 'flags', 64-bit Arm under 'Features' (BF16 as 'bf16')
    flags = {f for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith(("flags", "Features"))
             for f in line.split(":", 1)[1].split()}
    assert precision.cpu_has_bf16() == bool({"avx512_bf16", "amx_tile", "bf16"} & flags)


def test_cpu_bf16_probe_asks_the_architectures_own_extension(monkeypatch):
    def probes(avx512_bf16, amx, arm_bf16):
        monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: avx512_bf16)
        monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx)
        monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda: arm_bf16)

    probes(False, False, True)  # the Arm probe says AVX-512 on x86: not bf16 instructions there
    assert not precision.cpu_has_bf16("x86_64") and precision.cpu_has_bf16("aarch64")
    assert precision.cpu_has_bf16("arm64")  # macOS spells 64-bit Arm so
    probes(True, False, False)
    assert precision.cpu_has_bf16("x86_64") and precision.cpu_has_bf16("AMD64")  # Windows spells it so
    assert not precision.cpu_has_bf16("aarch64")
    probes(False, True, False)
    assert precision.cpu_has_bf16("x86_64")
    assert not precision.cpu_has_bf16("riscv64") and not precision.cpu_has_bf16("ppc64le")
    monkeypatch.delattr(torch.cpu, "_is_avx512_bf16_supported")  # a torch without the probe
    assert not precision.cpu_has_bf16("x86_64")
