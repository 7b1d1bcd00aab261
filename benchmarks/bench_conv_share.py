"""How close the training step's convolutions come to the device's peak; prints JSON.

For one preset, sim2real's training step (two views + one real image, L_vc on, bf16 autocast
and channels-last on CUDA, fp32 on the CPU) is run for warm-up steps, then

* the convolution FLOPs of one step are counted, forward and backward, with
  ``torch.utils.flop_counter`` (2 per multiply-add; the sub-pixel up-steps count as the
  convolutions they run);
* ``--steps`` steps are timed without a profiler (median s/it), and as many again under
  ``torch.profiler``: the time of ``aten::convolution`` and ``aten::convolution_backward``
  (device time of their kernels on CUDA, CPU time on the CPU), per step.

Reported: convolution TFLOP/s achieved while convolving, its share of the peak, and the
convolutions' share of the step. Peak: the dense bf16 tensor-core figure of the GPU from
NVIDIA's data sheets (H100 SXM / H200: 989 TFLOP/s, H100 NVL: 835, H100 PCIe: 756,
A100: 312, L40S: 362), or ``--peak-tflops``. On the CPU there is no data-sheet figure: the
faster of a 2048^3 matmul and a 256-channel 3x3 convolution at 64x128, measured in the same
process in fp32, stands in as a practical peak.

Usage: python benchmarks/bench_conv_share.py [--preset paper] [--device cuda|cpu] [--steps 5]
       [--peak-tflops T]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_train import _inputs, _sync  # noqa: E402

CONV_OPS = ("aten::convolution", "aten::convolution_backward")
BF16_PEAK_TFLOPS = (  # dense, no sparsity; first match of the device name wins
    ("H200", 989.0), ("H100 NVL", 835.0), ("H100 PCIe", 756.0), ("H100", 989.0),
    ("A100", 312.0), ("L40S", 362.0),
)


def data_sheet_peak(name: str) -> float | None:
    for key, tflops in BF16_PEAK_TFLOPS:
        if key.lower() in name.lower():
            return tflops
    return None


def seconds(fn, device: torch.device, repeats: int) -> list[float]:
    """Wall-clock seconds of ``repeats`` calls of ``fn``, synchronised on CUDA."""
    times = []
    for _ in range(repeats):
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
    return times


def practical_peak_tflops(device: torch.device, repeats: int = 5) -> float:
    """fp32 TFLOP/s of the faster of a 2048^3 matmul and a 256 -> 256 channel 3x3 convolution
    at 64x128 (on AMD CPUs the matmul library can be the slower one), median of ``repeats``."""
    n, c, h, w = 2048, 256, 64, 128
    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    x, k = torch.randn(1, c, h + 2, w + 2, device=device), torch.randn(c, c, 3, 3, device=device)
    rates = []
    for fn, flops in ((lambda: torch.mm(a, b), 2 * n**3), (lambda: torch.conv2d(x, k), 2 * c * c * 9 * h * w)):
        fn()  # warm-up
        rates.append(flops / statistics.median(seconds(fn, device, repeats)) / 1e12)
    return max(rates)


def conv_flops(step) -> int:
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        step()
    counts = counter.get_flop_counts().get("Global", {})
    return int(sum(v for op, v in counts.items() if str(op) in ("aten.convolution", "aten.convolution_backward")))


def conv_seconds(step, device: torch.device, steps: int) -> float:
    """Seconds per step inside the convolution ops (kernel time on CUDA, CPU time on the CPU)."""
    from torch.profiler import ProfilerActivity, profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=acts) as prof:
        for _ in range(steps):
            step()
        _sync(device)
    total_us = 0.0
    for e in prof.key_averages():
        if e.key in CONV_OPS:
            if device.type == "cuda":
                total_us += getattr(e, "device_time_total", None) or getattr(e, "cuda_time_total", 0.0)
            else:
                total_us += e.cpu_time_total
    return total_us / 1e6 / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper", choices=("tiny", "small", "paper"))
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu", choices=("cpu", "cuda"))
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--peak-tflops", type=float, default=None, help="override the peak (TFLOP/s)")
    args = ap.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        raise SystemExit("bench_conv_share: --device cuda, but no CUDA device is available")

    from torch.utils.data import default_collate

    from sim2real.config import override
    from sim2real.data.datasets import TrainPairs, resolve_scenes
    from sim2real.data.real import RealImages
    from sim2real.engine.trainer import Trainer
    from sim2real.presets import preset as get_preset

    with tempfile.TemporaryDirectory(prefix="bench_conv_") as tmp:
        base = Path(tmp)
        scene, real = _inputs(base)
        cfg = override(get_preset(args.preset), ["method.vc_start=0", f"device={args.device}", "data.workers=0",
                                                 "data.view_pool=0"])  # batches made here: no pool to ray-cast
        trainer = Trainer(cfg, [scene], real, base / "run", progress=False)
        device = trainer.device
        ds = TrainPairs(resolve_scenes([scene], cfg.data.height, cfg.data.width), RealImages(real), cfg.data, seed=0)
        batches = [trainer._to_device(default_collate([ds[s]])) for s in range(4)]
        k = [0]

        def step():
            trainer.train_step(batches[k[0] % len(batches)], k[0])
            k[0] += 1

        for _ in range(args.warmup):
            step()
        times = seconds(step, device, args.steps)
        flops = conv_flops(step)
        conv_s = conv_seconds(step, device, args.steps)
        peak_mem = torch.cuda.max_memory_allocated() / 2**20 if device.type == "cuda" else None

    step_s = statistics.median(times)
    achieved = flops / conv_s / 1e12 if conv_s > 0 else None
    if device.type == "cuda":
        name = torch.cuda.get_device_name(device)
        peak = args.peak_tflops or data_sheet_peak(name)
        peak_kind = "--peak-tflops" if args.peak_tflops else ("data sheet, dense bf16" if peak else None)
    else:
        name = f"{platform.machine()} CPU, {torch.get_num_threads()} threads"
        peak = args.peak_tflops or practical_peak_tflops(device)
        peak_kind = "--peak-tflops" if args.peak_tflops else "measured: fp32 matmul or 256-channel 3x3 conv, the faster"
    print(json.dumps({
        "benchmark": "conv_share", "preset": args.preset, "device": name, "torch": str(torch.__version__),
        "amp_bf16": trainer.amp, "s_per_iteration": round(step_s, 5), "iterations_per_s": round(1 / step_s, 3),
        "conv_tflop_per_step": round(flops / 1e12, 4), "conv_s_per_step": round(conv_s, 5),
        "conv_share_of_step": round(conv_s / step_s, 3), "conv_tflops_achieved": achieved and round(achieved, 4),
        "peak_tflops": peak and round(peak, 4), "peak_kind": peak_kind,
        "conv_share_of_peak": round(achieved / peak, 4) if achieved and peak else None,
        "peak_gpu_memory_mb": peak_mem and round(peak_mem, 1),
    }, indent=2))


if __name__ == "__main__":
    main()
