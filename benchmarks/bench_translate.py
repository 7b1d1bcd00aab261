"""Frames per second of ``translate`` at 256x512 for the small and paper presets; prints JSON.

For each preset it builds a run at step 0 (untrained weights: the speed does not depend on their
values) on a procedural scene, then measures

* ``model_fps``: :meth:`TrainedModel.translate_gbuffers` alone on pre-rendered G-buffers
  (texture projection + reference rendering + E_A/G_B), batch ``--batch`` (8 unless given, on
  every device; ``sim2real translate`` sends 2 on a CPU), median of
  ``--repeats`` timed passes over ``--frames`` frames after one warm-up pass;
* ``end_to_end_fps`` (``--end-to-end``): :func:`translate_sequence` over a trajectory of
  ``--frames`` frames: ray casting, translation, PNG frames, H.264 video and the ground-truth
  export, as ``sim2real translate`` runs it;
* ``pipeline_fps`` (``--pipeline``): the same command with the network replaced by a_ref (each
  frame is its reference rendering): what everything but the network allows, the ceiling a
  GPU's translation meets. On a CPU the network dominates ``end_to_end_fps``.

``--precisions auto,fp32,bf16`` measures each network arithmetic (``sim2real translate
--precision``; 'auto' is the run's bf16 with channels-last on CUDA, fp32 on the CPU), each
timed pass alternating between them, and reports every later precision's frames against the
first's: mean, 99th percentile and largest absolute difference in 8-bit levels. A precision with
``+compile`` (``fp32+compile``, ``bf16+compile``) is the same with ``sim2real translate
--compile``; its ``warmup_seconds`` (the first pass, which compiles) against the others' says
how many frames the compiling costs.
Beside the frame rates, ``network_gflop_per_frame`` counts the networks' convolution and matrix
FLOPs of one frame (``torch.utils.flop_counter``), ``matmul_gflops`` measures what this device
attains on a large matrix product in each precision (the practical ceiling of those FLOPs), and
each precision's ``network_gflops`` and ``share_of_matmul_rate`` say how near the networks run
to it; ``network_fps_at_matmul_rate`` is the frame rate the networks would allow at that ceiling,
the most any change short of a smaller network or faster hardware could give.
``--run RUN --scene SCENE`` times a trained run at its own size (for example the demo's
``demo/run`` with ``demo/scenes/sim_0``) instead of untrained presets at 256x512: the frame
differences of a trained model are the ones that matter.

Usage: python benchmarks/bench_translate.py [--presets small,paper | --run RUN --scene SCENE]
       [--device cpu|cuda] [--precisions auto[,bf16+compile...]] [--frames 16] [--batch 8] [--repeats 3]
       [--end-to-end] [--workers N] [--pipeline]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from sim2real.engine.precision import cpu_has_bf16


class _ARefSequence:
    """A stand-in for the network: each frame is its view's reference rendering."""

    def translate(self, chunk):
        from sim2real.render.reference import reference_rendering, to_uint8

        return [to_uint8(reference_rendering(g)) for g in chunk]


def make_run(preset: str, scene_dir: Path, real_dir: Path, out: Path, device: str) -> Path:
    from sim2real.config import override
    from sim2real.engine.trainer import Trainer
    from sim2real.presets import preset as get_preset

    # data.view_pool=0: only the step-0 checkpoint is needed, not the preset's pool of 3,000 ray-cast views
    cfg = override(get_preset(preset), [f"device={device}", "data.height=256", "data.width=512", "data.view_pool=0"])
    trainer = Trainer(cfg, scenes=[str(scene_dir)], real=str(real_dir), out=out, progress=False)
    try:
        trainer.save_checkpoint()
    finally:
        trainer.close()
    return out


def _levels(frames, ref) -> dict:
    """Absolute differences of ``frames`` from ``ref`` in 8-bit levels: mean, 99th percentile, max."""
    d = np.concatenate([np.abs(a.astype(np.int16) - b.astype(np.int16)).ravel() for a, b in zip(frames, ref)])
    return {"mean": round(float(d.mean()), 3), "p99": float(np.percentile(d, 99)), "max": int(d.max())}


def _timed(model, scene_name, gbuffers, batch) -> tuple[float, list]:
    if model.device.type == "cuda":
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    frames = model.translate_gbuffers(scene_name, gbuffers, batch)
    if model.device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - t0, frames


def count_gflop(fn) -> float:
    """Convolution and matrix GFLOP that ``fn()`` runs, as ``torch.utils.flop_counter`` counts them
    (a convolution: 2 cin cout k_h k_w h_out w_out per sample; the sub-pixel up-step as the
    convolutions it runs). Run ``fn`` under ``torch.no_grad``, not inference mode, under which
    torch 2.5's counter sees nothing (it counts 0)."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops() / 1e9


def _network_gflop(run, device, scene_name, gbuffer) -> float:
    """GFLOP of one frame through the run's networks (eager, fp32), as ``translate`` runs them but
    outside inference mode (:func:`count_gflop`)."""
    from sim2real.inference.model import load_run

    model = load_run(run, device=device, precision="fp32")
    translator = model.sequence(scene_name, batch=1).translator  # the method's, without inference mode
    with torch.no_grad():
        return count_gflop(lambda: translator.push([gbuffer]))


def _matmul_gflops(device: str, dtype: torch.dtype, repeats: int = 10) -> float:
    """GFLOP/s of an n x n by n x n matrix product on ``device`` (2 n^3 FLOP), the best of ``repeats``
    (a ceiling is what the hardware reaches; a busy spell only lowers it: medians of five ranged
    from 119 to 181 GFLOP/s on an idle 2-core CPU), after a second of fp32 products. n grows
    from 512 while a product takes under 50 ms, up to 2048 on the CPU and 8192 on a GPU (emulated
    bf16 on a CPU without bf16 instructions runs at about 1 GFLOP/s)."""

    def seconds(a, b) -> float:
        if device == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        torch.mm(a, b)
        if device == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter() - t0

    n, cap = 512, 8192 if device == "cuda" else 2048
    warm = time.perf_counter() + 1.0  # the first second after start-up runs slower (measured 124 against 160-180)
    a = torch.randn(512, 512, device=device)
    while time.perf_counter() < warm:
        seconds(a, a)
    while True:
        a, b = (torch.randn(n, n, device=device).to(dtype) for _ in range(2))
        seconds(a, b)  # warms up
        if n >= cap or seconds(a, b) >= 0.05:
            break
        n *= 2
    return 2 * n**3 / min(seconds(a, b) for _ in range(repeats)) / 1e9


def _cpu_seconds() -> float:
    """User and system CPU seconds of this process and of its children that have ended."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> None:
    from sim2real.inference.model import load_run
    from sim2real.inference.translate import trajectory_source, translate_sequence
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.procedural import generate_scene
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="small,paper")
    ap.add_argument("--run", help="a trained run folder to time instead of the presets (needs --scene)")
    ap.add_argument("--scene", help="a scene folder of --run")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precisions", default="auto", help="comma-separated: auto, fp32, bf16, each optionally +compile")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--end-to-end", action="store_true")
    ap.add_argument("--workers", type=int, help="ray-casting processes of the end-to-end runs (default: automatic)")
    ap.add_argument("--pipeline", action="store_true", help="also time the command with a_ref for the network")
    args = ap.parse_args()
    if bool(args.run) != bool(args.scene):
        raise SystemExit("give --run RUN and --scene SCENE together")
    precisions = args.precisions.split(",")
    matmul = {name: round(_matmul_gflops(args.device, dtype), 1)
              for name, dtype in (("fp32", torch.float32), ("bf16", torch.bfloat16))}

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.run:
            scene_dir = Path(args.scene)
            scene = Scene.load(scene_dir)
            runs = {"run": Path(args.run)}
        else:
            scene = generate_scene(0)
            scene_dir = scene.save(tmp / "scene")
            real = tmp / "real"
            real.mkdir()
            rng = np.random.default_rng(0)
            for k in range(4):
                Image.fromarray(rng.integers(0, 255, (300, 600, 3), dtype=np.uint8)).save(real / f"{k}.png")
            runs = {name: make_run(name, scene_dir, real, tmp / f"run_{name}", args.device)
                    for name in args.presets.split(",")}
        caster = RayCaster(scene)

        results = {}
        for name, run in runs.items():
            models = {p: load_run(run, device=args.device, precision=p.removesuffix("+compile"),
                                  compile=p.endswith("+compile")) for p in precisions}
            first = models[precisions[0]]
            h, w = first.train_size if args.run else (256, 512)
            traj = make_trajectory(caster, args.frames, h, w, first.cfg.data.fov_x_deg, seed=0)
            traj.save(tmp / "traj.txt")
            gbuffers = [caster.render(c) for c in traj.cameras]
            gflop = _network_gflop(run, args.device, scene.name, gbuffers[0])
            res = {"height": h, "width": w, "generator_filters": first.cfg.generator.filters,
                   "network_gflop_per_frame": round(gflop, 2),
                   "precisions": {p: {"amp_bf16": m.amp} for p, m in models.items()}}
            if args.repeats > 0:  # --repeats 0: no model timing (e.g. for --pipeline alone)
                times = {p: [] for p in precisions}
                warm = {p: _timed(m, scene.name, gbuffers, args.batch) for p, m in models.items()}
                frames = {p: w[1] for p, w in warm.items()}
                for _ in range(args.repeats):  # alternating, so that a slow spell of the machine hits each alike
                    for p, m in models.items():
                        times[p].append(_timed(m, scene.name, gbuffers, args.batch)[0])
                for p in precisions:
                    r = res["precisions"][p]
                    fps = args.frames / statistics.median(times[p])
                    ceiling = matmul["bf16" if models[p].amp else "fp32"]
                    r.update(model_fps=fps, model_seconds=times[p], warmup_seconds=warm[p][0],
                             network_gflops=round(gflop * fps, 1), share_of_matmul_rate=round(gflop * fps / ceiling, 3),
                             network_fps_at_matmul_rate=round(ceiling / gflop, 2))
                    if p != precisions[0]:
                        r[f"levels_vs_{precisions[0]}"] = _levels(frames[p], frames[precisions[0]])
            for p, model in models.items():
                r = res["precisions"][p]
                if args.end_to_end:
                    t0 = time.perf_counter()
                    translate_sequence(model, trajectory_source(model, scene_dir, tmp / "traj.txt"),
                                       tmp / f"out_{name}_{p}", batch=args.batch, workers=args.workers, progress=False)
                    r["end_to_end_fps"] = args.frames / (time.perf_counter() - t0)
            if args.pipeline:
                model = load_run(run, device=args.device)
                model.sequence = lambda scene_name, batch: _ARefSequence()
                t0, c0 = time.perf_counter(), _cpu_seconds()
                m = translate_sequence(model, trajectory_source(model, scene_dir, tmp / "traj.txt"),
                                       tmp / f"pipe_{name}", batch=args.batch, workers=args.workers, progress=False)
                wall = time.perf_counter() - t0
                res["pipeline_fps"] = args.frames / wall
                # CPU seconds of this process and its finished workers per wall second: below the
                # core count, cores idle (there overlapping more stages would pay)
                res["pipeline_busy_cores"] = (_cpu_seconds() - c0) / wall
                # the share of the command after its last frame: the ground truth still to be written
                res["pipeline_ground_truth_share"] = 1 - m["seconds"]["translate"] / m["seconds"]["total"]
            results[name] = res

    print(json.dumps({
        "benchmark": "translate", "frames": args.frames, "batch": args.batch,
        "workers": args.workers, "device": args.device, "cuda_name": torch.cuda.get_device_name() if args.device == "cuda" else None,
        "cpu_native_bf16": cpu_has_bf16(), "matmul_gflops": matmul,
        "machine": platform.machine(), "cpus": os.cpu_count(), "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(), "runs": results,
    }, indent=2))


if __name__ == "__main__":
    main()
