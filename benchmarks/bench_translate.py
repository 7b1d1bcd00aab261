"""Frames per second of ``translate`` at 256x512 for the small and paper presets; prints JSON.

For each preset it builds a run at step 0 (untrained weights: the speed does not depend on their
values) on a procedural scene, then measures

* ``model_fps``: :meth:`TrainedModel.translate_gbuffers` alone on pre-rendered G-buffers
  (texture projection + reference rendering + E_A/G_B), batch ``--batch``, median of
  ``--repeats`` timed passes over ``--frames`` frames after one warm-up pass;
* ``end_to_end_fps`` (``--end-to-end``): :func:`translate_sequence` over a trajectory of
  ``--frames`` frames: ray casting, translation, PNG frames, H.264 video and the ground-truth
  export, as ``sim2real translate`` runs it;
* ``pipeline_fps`` (``--pipeline``): the same command with the network replaced by a_ref (each
  frame is its reference rendering): what everything but the network allows, the ceiling a
  GPU's translation meets. On a CPU the network dominates ``end_to_end_fps``.

On CUDA the run's ``amp`` (bf16) and channels-last are used, as in ``sim2real translate``.

Usage: python benchmarks/bench_translate.py [--presets small,paper] [--device cpu|cuda]
       [--frames 16] [--batch 8] [--repeats 3] [--end-to-end] [--pipeline]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image


class _ARefSequence:
    """A stand-in for the network: each frame is its view's reference rendering."""

    def translate(self, chunk):
        from sim2real.render.reference import reference_rendering, to_uint8

        return [to_uint8(reference_rendering(g)) for g in chunk]


def make_run(preset: str, scene_dir: Path, real_dir: Path, out: Path, device: str) -> Path:
    from sim2real.config import override
    from sim2real.engine.trainer import Trainer
    from sim2real.presets import preset as get_preset

    cfg = override(get_preset(preset), [f"device={device}", "data.height=256", "data.width=512"])
    trainer = Trainer(cfg, scenes=[str(scene_dir)], real=str(real_dir), out=out, progress=False)
    try:
        trainer.save_checkpoint()
    finally:
        trainer.close()
    return out


def main() -> None:
    from sim2real.inference.translate import load_run, trajectory_source, translate_sequence
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.procedural import generate_scene
    from sim2real.scene.trajectory import make_trajectory

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="small,paper")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--end-to-end", action="store_true")
    ap.add_argument("--pipeline", action="store_true", help="also time the command with a_ref for the network")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene = generate_scene(0)
        scene_dir = scene.save(tmp / "scene")
        real = tmp / "real"
        real.mkdir()
        rng = np.random.default_rng(0)
        for k in range(4):
            Image.fromarray(rng.integers(0, 255, (300, 600, 3), dtype=np.uint8)).save(real / f"{k}.png")
        caster = RayCaster(scene)
        traj = make_trajectory(caster, args.frames, 256, 512, seed=0)
        traj.save(tmp / "traj.txt")
        gbuffers = [caster.render(c) for c in traj.cameras]

        results = {}
        for name in args.presets.split(","):
            run = make_run(name, scene_dir, real, tmp / f"run_{name}", args.device)
            model = load_run(run, device=args.device)
            res = {"amp_bf16": model.amp, "generator_filters": model.cfg.generator.filters}
            if args.repeats > 0:  # --repeats 0: no model timing (e.g. for --pipeline alone)
                model.translate_gbuffers(scene.name, gbuffers, args.batch)  # warm-up
                times = []
                for _ in range(args.repeats):
                    if model.device.type == "cuda":
                        torch.cuda.synchronize()
                    t0 = time.perf_counter()
                    model.translate_gbuffers(scene.name, gbuffers, args.batch)
                    if model.device.type == "cuda":
                        torch.cuda.synchronize()
                    times.append(time.perf_counter() - t0)
                res.update(model_fps=args.frames / statistics.median(times), model_seconds=times)
            if args.end_to_end:
                t0 = time.perf_counter()
                translate_sequence(model, trajectory_source(model, scene_dir, tmp / "traj.txt"),
                                   tmp / f"out_{name}", batch=args.batch, progress=False)
                res["end_to_end_fps"] = args.frames / (time.perf_counter() - t0)
            if args.pipeline:
                model.sequence = lambda scene_name, batch: _ARefSequence()
                t0 = time.perf_counter()
                translate_sequence(model, trajectory_source(model, scene_dir, tmp / "traj.txt"),
                                   tmp / f"pipe_{name}", batch=args.batch, progress=False)
                res["pipeline_fps"] = args.frames / (time.perf_counter() - t0)
            results[name] = res

    print(json.dumps({
        "benchmark": "translate", "height": 256, "width": 512, "frames": args.frames, "batch": args.batch,
        "device": args.device, "cuda_name": torch.cuda.get_device_name() if args.device == "cuda" else None,
        "machine": platform.machine(), "cpus": os.cpu_count(), "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(), "presets": results,
    }, indent=2))


if __name__ == "__main__":
    main()
