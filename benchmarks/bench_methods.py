"""Every method's cost in one run: training seconds per iteration and translation frames/s; prints JSON.

For each size preset and each method preset (sim2real.presets.METHOD_PRESETS):

* ``s_per_iteration``: median of :meth:`Trainer.train_step` on pre-drawn batches of the method's
  own training data (view pairs, single views or triplets; data loading is not timed: it runs in
  DataLoader workers during training), after warm-up steps; view consistency is on from step 0;
* ``ratio_to_ours``: that median over ours' (the image baselines should cost about half: one view
  instead of two, no texture);
* ``translate_frames_per_s``: a trained-for-0-steps model translating pre-rendered G-buffers of a
  trajectory through ``load_run(...).sequence(...)`` (batch 8; OF-UNIT is sequential, frame by
  frame).

All methods of a preset run in one process, one after the other, so compare the ratios; the
machine's load shifts absolute figures.

Usage: python benchmarks/bench_methods.py [--presets small,paper] [--iters small=6,paper=2]
       [--methods ours,ssim_munit,...] [--device cpu|cuda]
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

WARMUP = {"tiny": 2, "small": 2, "paper": 1}


def _inputs(base: Path, height: int, width: int) -> tuple[Path, Path]:
    """A procedural scene and a small real folder with images and one sequence."""
    import numpy as np
    from PIL import Image

    from sim2real.scene.procedural import generate_scene

    scene = base / "scene"
    if not scene.exists():
        generate_scene(0).save(scene)
    real = base / "real"
    if not real.exists():
        rng = np.random.default_rng(0)
        (real / "images").mkdir(parents=True)
        (real / "sequences" / "000" / "images").mkdir(parents=True)
        for k in range(4):
            Image.fromarray(rng.integers(0, 256, (height, width, 3), dtype=np.uint8)).save(real / "images" / f"r{k}.png")
            Image.fromarray(rng.integers(0, 256, (height, width, 3), dtype=np.uint8)).save(
                real / "sequences" / "000" / "images" / f"{k:04d}.png")
    return scene, real


def _sync(device) -> None:
    import torch

    if device.type == "cuda":
        torch.cuda.synchronize(device)


def measure(preset: str, method: str, iters: int, device: str, base: Path, frames: int) -> dict:
    from torch.utils.data import default_collate

    from sim2real.config import override
    from sim2real.engine.trainer import Trainer
    from sim2real.inference.frames import iter_gbuffers
    from sim2real.inference.model import load_run
    from sim2real.presets import preset as get_preset
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    cfg = get_preset(preset, method)
    # data.view_pool=0: a handful of batches is drawn, so a pool (3,000 views ray-cast) would only cost time
    sets = [f"device={device}", "data.workers=0", "data.view_pool=0", "checkpoint_every=1000000", "image_every=1000000"]
    if hasattr(cfg.method, "vc_start"):
        sets.append("method.vc_start=0")
    cfg = override(cfg, sets)
    scene, real = _inputs(base, cfg.data.height, cfg.data.width)
    run = base / f"run_{preset}_{method}"
    trainer = Trainer(cfg, [scene], real / "images", run, progress=False)
    try:
        n = WARMUP[preset] + iters
        batches = [trainer._to_device(default_collate([trainer.dataset[s]])) for s in range(n)]
        times = []
        for s, batch in enumerate(batches):
            _sync(trainer.device)
            t = time.perf_counter()
            trainer.train_step(batch, s)
            _sync(trainer.device)
            times.append(time.perf_counter() - t)
        trainer.save_checkpoint()
    finally:
        trainer.close()
    out = {"s_per_iteration": round(statistics.median(times[WARMUP[preset]:]), 4), "timed_iterations": iters,
           "data": trainer.method.data}
    caster = RayCaster(Scene.load(scene))
    traj = make_trajectory(caster, frames, cfg.data.height, cfg.data.width, cfg.data.fov_x_deg, seed=0)
    gbuffers = list(iter_gbuffers(scene, traj.cameras, None, 8, caster=caster))
    model = load_run(run, device=device)
    model.sequence(Scene.load(scene).name).translate(gbuffers[:8])  # warm-up
    t = time.perf_counter()
    model.sequence(Scene.load(scene).name).translate(gbuffers)
    out["translate_frames_per_s"] = round(len(gbuffers) / (time.perf_counter() - t), 3)
    out["time_independent"] = model.time_independent
    return out


def main() -> None:
    from sim2real.presets import METHOD_PRESETS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="small,paper")
    ap.add_argument("--iters", default="tiny=6,small=6,paper=2", help="timed iterations per preset")
    ap.add_argument("--methods", default=",".join(METHOD_PRESETS))
    ap.add_argument("--frames", type=int, default=24, help="frames translated per method")
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    args = ap.parse_args()
    iters = {k: int(v) for k, v in (p.split("=") for p in args.iters.split(","))}
    methods = args.methods.split(",")
    result = {"machine": platform.processor() or platform.machine(), "python": sys.version.split()[0], "presets": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets.split(","):
            rows = {}
            for m in methods:
                print(f"bench_methods: {preset} {m}", file=sys.stderr, flush=True)
                rows[m] = measure(preset, m, iters[preset], args.device, Path(tmp), args.frames)
            if "ours" in rows:
                for r in rows.values():
                    r["ratio_to_ours"] = round(r["s_per_iteration"] / rows["ours"]["s_per_iteration"], 3)
            result["presets"][preset] = rows
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
