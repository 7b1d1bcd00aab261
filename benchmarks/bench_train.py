"""Training throughput: sim2real's trainer vs a step organised like the authors' release; prints JSON.

For each preset: iterations/s of the training step (two views + one real image, L_vc on) and
the process's peak memory (max RSS on CPU, max allocated on CUDA), for

* ``ours``: :class:`sim2real.engine.trainer.Trainer.train_step`;
* ``reference``: benchmarks/authors_reference.py (translations recomputed for the
  discriminator step, whole-texture tanh + gather/scatter projection with precomputed index
  lists, plain Adam);

and their ratio (of the median step times; ``paired_ratio_median`` is the median over rounds of
reference/ours step time, each round running the two back to back). On CUDA, ``ours`` also
reports ``host_syncs``: the calls of its step that make the host wait for the GPU, by source line
(:func:`host_syncs`) and ``device_busy``: the share of the step's wall time in which the GPU
ran kernels or copies (:func:`device_busy`; well below 1, the GPU waits for the host). Both run on the same
pre-generated batches (data loading is not timed; it
runs in DataLoader workers during training). Timing runs both implementations in one process,
alternating step by step, so that load from other processes hits both alike; peak memory comes
from a fresh process per implementation. Also: texture projection forward + backward (ms) at
256x512 with a 512^2 texture of 5 objects, both formulations.

Usage: python benchmarks/bench_train.py [--presets tiny,small,paper] [--iters tiny=20,small=5,paper=2]
       [--device cpu|cuda]
The paper preset takes ~30 s per iteration on a 2-core CPU: it gets 1 warm-up + 2 timed
iterations by default; leave it out with --presets tiny,small.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
WARMUP = {"tiny": 3, "small": 2, "paper": 1}


def _inputs(base: Path) -> tuple[Path, Path]:
    import numpy as np
    from PIL import Image

    from sim2real.scene.procedural import generate_scene

    scene = base / "scene"
    if not scene.exists():
        generate_scene(0).save(scene)
    real = base / "real"
    if not real.exists():
        real.mkdir()
        rng = np.random.default_rng(0)
        for k in range(4):
            Image.fromarray(rng.integers(0, 256, (540, 960, 3), dtype=np.uint8)).save(real / f"r{k}.png")
    return scene, real


def _sync(device):
    import torch

    if device.type == "cuda":
        torch.cuda.synchronize()


def _runners(impls, cfg, scene, real, sources, batches, base, device_name):
    """One ``run(step)`` per implementation, each on its own copy of the batches."""
    import torch

    runners = {}
    for impl in impls:
        if impl == "ours":
            from sim2real.engine.trainer import Trainer

            trainer = Trainer(cfg, [scene], real, Path(tempfile.mkdtemp(dir=base)) / "run", progress=False)
            bs = [trainer._to_device(b) for b in batches]
            runners[impl] = (trainer.device, lambda s, t=trainer, bs=bs: t.train_step(bs[s], s))
        else:
            sys.path.insert(0, str(HERE))
            from authors_reference import AuthorsStyleTrainer

            device = torch.device("cuda" if device_name == "cuda" else "cpu")
            ref = AuthorsStyleTrainer(cfg, sources, device)
            from sim2real.data.tensors import complete_on_device, widen

            bs = [complete_on_device(widen({k: v.to(device) if k not in ("scene", "step") else v for k, v in b.items()}))
                  for b in batches]
            lists = [ref.precompute(b) for b in bs]  # offline index lists: not timed
            runners[impl] = (device, lambda s, r=ref, bs=bs, li=lists: r.train_step(bs[s], li[s], s))
    return runners


SYNC_WARNING = "synchronizing CUDA operation"
"""What torch's sync debug mode warns of each call that makes the host wait for the GPU."""


def host_syncs(run, steps: list[int]) -> dict:
    """The calls that wait for the GPU during ``run(step)`` for ``steps``
    (``torch.cuda.set_sync_debug_mode("warn")``), counted by the source line that made them: a
    training step should make one (the trainer's NaN check, engine/trainer.py); each other one
    drains the GPU's queue."""
    import collections
    import warnings

    import torch

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            for s in steps:
                run(s)
        finally:
            torch.cuda.set_sync_debug_mode(0)
    sites = collections.Counter(f"{Path(w.filename).name}:{w.lineno}" for w in caught if SYNC_WARNING in str(w.message))
    return {"per_step": round(sum(sites.values()) / max(len(steps), 1), 2), "steps": len(steps),
            "sites": dict(sites.most_common(20))}


def busy_share(intervals: list[tuple[float, float]], wall: float) -> float:
    """The length of the union of ``intervals`` (start, end) over ``wall`` (same unit): overlapping
    kernels (two streams) count once."""
    busy, end = 0.0, float("-inf")
    for a, b in sorted(intervals):
        if b > end:
            busy += b - max(a, end)
            end = b
    return busy / wall if wall > 0 else 0.0


def device_busy(run, steps: list[int], device: str = "cuda") -> dict:
    """``run(step)`` for ``steps`` under torch.profiler: the share of their wall time (from before the
    first to after the last, synchronised) covered by the device's activity, kernels and copies on
    CUDA (on the CPU the operators, for the tests). On a GPU a share well below 1 means the GPU
    waits for the host (operator launches, syncs): fewer, fused kernels (``torch.compile``) or
    CUDA graphs would pay there; near 1, the GPU's arithmetic bounds the step."""
    import torch
    from torch.autograd import DeviceType
    from torch.profiler import ProfilerActivity, profile

    cuda = device == "cuda"
    with profile(activities=[ProfilerActivity.CUDA if cuda else ProfilerActivity.CPU]) as prof:
        _sync(torch.device(device))
        t0 = time.perf_counter()
        for s in steps:
            run(s)
        _sync(torch.device(device))
        wall = time.perf_counter() - t0
    kind = DeviceType.CUDA if cuda else DeviceType.CPU
    spans = [(e.time_range.start, e.time_range.end) for e in prof.events() if e.device_type == kind]
    return {"busy_share": round(busy_share(spans, wall * 1e6), 3), "steps": len(steps),
            "seconds_per_step": round(wall / max(len(steps), 1), 4)}


def child(preset: str, impls: list[str], iters: int, base: Path, device_name: str) -> dict:
    """Time ``impls`` on the same batches, alternating step by step (so that a varying load
    from other processes hits both alike); the peak memory is meaningful for one impl only."""
    import torch
    from torch.utils.data import default_collate

    from sim2real.config import override
    from sim2real.data.datasets import TrainPairs, resolve_scenes
    from sim2real.data.real import RealImages
    from sim2real.presets import preset as get_preset

    scene, real = _inputs(base)
    # data.view_pool=0: the batches are made here, so a pool (3,000 views ray-cast) would only cost time
    cfg = override(get_preset(preset), ["method.vc_start=0", f"device={device_name}", "data.workers=0", "data.view_pool=0"])
    sources = resolve_scenes([scene], cfg.data.height, cfg.data.width)
    ds = TrainPairs(sources, RealImages(real), cfg.data, seed=0)
    n = WARMUP[preset] + iters
    batches = [default_collate([ds[s]]) for s in range(n)]
    runners = _runners(impls, cfg, scene, real, sources, batches, base, device_name)
    times = {impl: [] for impl in impls}
    for s in range(n):
        for impl, (device, run) in runners.items():
            _sync(device)
            t = time.perf_counter()
            run(s)
            _sync(device)
            times[impl].append(time.perf_counter() - t)
    device = next(iter(runners.values()))[0]
    if device.type == "cuda":
        peak_mb, kind = torch.cuda.max_memory_allocated() / 2**20, "CUDA max allocated"
    else:
        peak_mb, kind = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "max RSS"
    result = {"peak_memory_mb": round(peak_mb, 1), "memory_kind": kind}
    for impl, ts in times.items():
        timed = ts[WARMUP[preset]:]
        if not timed:  # a memory-only run
            continue
        med = statistics.median(timed)
        result[impl] = {"s_per_iteration": round(med, 4), "iterations_per_s": round(1.0 / med, 4),
                        "timed_iterations": len(timed)}
    if "ours" in runners and iters:
        device, run = runners["ours"]
        timed = list(range(WARMUP[preset], n))
        result["host_syncs"] = host_syncs(run, timed) if device.type == "cuda" else {
            "reason": "counted on CUDA only (torch.cuda.set_sync_debug_mode)"}
        result["device_busy"] = device_busy(run, timed) if device.type == "cuda" else {
            "reason": "measured on CUDA only (torch.profiler's CUDA activity)"}
    if {"ours", "reference"} <= set(times) and len(times["ours"]) > WARMUP[preset]:
        # the two steps of one round ran back to back: their ratio cancels slow drifts of the load
        pairs = [r / o for o, r in zip(times["ours"][WARMUP[preset]:], times["reference"][WARMUP[preset]:])]
        result["paired_ratio_median"] = round(statistics.median(pairs), 3)
    return result


def projection_ms(base: Path, repeats: int = 7) -> dict:
    import torch

    sys.path.insert(0, str(HERE))
    from authors_reference import GatherScatterTexture

    from sim2real.config import TextureConfig
    from sim2real.data.datasets import resolve_scenes
    from sim2real.data.tensors import view_tensors
    from sim2real.render.raycast import RayCaster
    from sim2real.render.reference import class_albedo
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import sample_poses
    from sim2real.texture.neural_texture import NeuralTexture

    scene, _ = _inputs(base)
    caster = RayCaster(Scene.load(scene))
    g = caster.render(sample_poses(caster, 1, 256, 512, 75.0, seed=3)[0])
    view = view_tensors([g], "i")
    oid, pts, nrm = view["object_id_i"], view["points_i"], view["normal_i"]
    src = resolve_scenes([scene], 256, 512)[0]
    cfg = TextureConfig(size=512)
    ours = NeuralTexture(len(src.classes), src.bounds, class_albedo(src.classes), cfg)
    ref = GatherScatterTexture(src, cfg)
    lists = ref.precompute(oid, pts, nrm)
    w = torch.randn(1, 3, 256, 512)

    def fwd_bwd(fn, param):
        param.grad = None
        t0 = time.perf_counter()
        (fn() * w).sum().backward()
        return (time.perf_counter() - t0) * 1000

    runs = {"ours": (lambda: ours(oid, pts, nrm), ours.texture), "reference": (lambda: ref(lists, oid.shape), ref.texture)}
    ms = {k: [] for k in runs}
    for i in range(repeats + 1):  # alternating, first round is warm-up
        for k, (fn, param) in runs.items():
            t = fwd_bwd(fn, param)
            if i:
                ms[k].append(t)

    return {"height": 256, "width": 512, "texture": [len(src.classes), 6, 512, 512, 3],
            "foreground_fraction": float(g.mask.mean()),
            "ours_fwd_bwd_ms": round(statistics.median(ms["ours"]), 1),
            "reference_fwd_bwd_ms": round(statistics.median(ms["reference"]), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="tiny,small,paper")
    ap.add_argument("--iters", default="tiny=20,small=5,paper=2")
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--child", nargs=4, metavar=("PRESET", "IMPLS", "ITERS", "BASE"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        p, impls, iters, base = args.child
        print(json.dumps(child(p, impls.split("+"), int(iters), Path(base), args.device)))
        return
    iters = dict(kv.split("=") for kv in args.iters.split(","))
    import torch

    result = {"benchmark": "train_step", "machine": f"{platform.machine()} {os.cpu_count()} cores",
              "torch": str(torch.__version__), "threads": torch.get_num_threads(), "device": args.device, "presets": {}}

    def run_child(preset, impls, n):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--device", args.device,
               "--child", preset, impls, str(n), str(base)]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode:
            raise SystemExit(f"{preset}/{impls} failed:\n{out.stderr}")
        return json.loads(out.stdout.strip().splitlines()[-1])

    with tempfile.TemporaryDirectory(prefix="bench_train_") as tmp:
        base = Path(tmp)
        _inputs(base)
        for preset in args.presets.split(","):
            # timing: both implementations in one process, alternating step by step
            both = run_child(preset, "ours+reference", int(iters.get(preset, 3)))
            entry = {impl: both[impl] for impl in ("ours", "reference")}
            # peak memory: each implementation alone in a fresh process (its warm-up steps)
            for impl in ("ours", "reference"):
                alone = run_child(preset, impl, 0)
                entry[impl]["peak_memory_mb"] = alone["peak_memory_mb"]
                entry[impl]["memory_kind"] = alone["memory_kind"]
            entry["throughput_ratio_ours_over_reference"] = round(
                entry["ours"]["iterations_per_s"] / entry["reference"]["iterations_per_s"], 2)
            entry["paired_ratio_median"] = both["paired_ratio_median"]
            entry["ours"]["host_syncs"] = both["host_syncs"]
            entry["ours"]["device_busy"] = both["device_busy"]
            result["presets"][preset] = entry
            print(json.dumps({preset: entry}), file=sys.stderr)
        result["projection"] = projection_ms(base)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
