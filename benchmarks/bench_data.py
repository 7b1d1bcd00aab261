"""Training-data throughput: samples/s of ``TrainPairs`` (two views + correspondences + one real
image per step), the ``data.workers`` a target iteration rate needs; prints JSON.

A GPU step of the paper preset is meant to take 50 ms (20 it/s), so the loader must deliver 20
samples/s or the GPU waits. Per preset and view source (fresh random poses ray-cast per sample,
or a views folder of cached G-buffers):

* ``s_per_sample``: median and mean over ``--samples`` samples in this process, one thread (as a
  DataLoader worker runs; the mean counts the redraws of view j below ``data.min_overlap``);
* ``workers_for_target``: ``ceil(target * mean)``, the workers needed at ``--target`` it/s
  if each has a core of this machine's speed;
* ``loader_samples_per_s``: through ``torch.utils.data.DataLoader`` with 1..``--max-workers``
  worker processes (the trainer's loader: batch 1, prefetch 4, one thread per worker), timed
  after the first batch.

Real images are 960x540 PNGs of random noise (a laparoscope's frame size; noise is the slowest to
decode), decoded, resized and cropped per
sample. Usage: python benchmarks/bench_data.py [--presets paper,small] [--samples 30]
[--max-workers N] [--target 20]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _inputs(base: Path, height: int, width: int, views: int) -> tuple[Path, Path, Path]:
    from sim2real.data.views import write_views_manifest
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import sample_poses

    sys.path.insert(0, str(HERE))
    from bench_train import _inputs as scene_and_real

    scene, real = scene_and_real(base)
    folder = base / f"views_{height}x{width}"
    if not folder.exists():
        s = Scene.load(scene)
        caster = RayCaster(s)
        for k, cam in enumerate(sample_poses(caster, views, height, width, 75.0, seed=7)):
            caster.render(cam).save(folder / f"view_{k:05d}.npz")
        write_views_manifest(folder, s.name, scene, views)
    return scene, real, folder


def _in_process(ds, n: int) -> dict:
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        ds[0]  # Embree BVH, direction cache
        times = []
        for s in range(1, n + 1):
            t = time.perf_counter()
            ds[s]
            times.append(time.perf_counter() - t)
    return {"median": round(statistics.median(times), 4), "mean": round(statistics.mean(times), 4)}


def _loader_rate(ds, workers: int, n: int) -> float:
    import torch

    from sim2real.data.datasets import StepSampler
    from sim2real.threads import single_thread_worker

    loader = torch.utils.data.DataLoader(ds, batch_size=1, sampler=StepSampler(0, n + 1), num_workers=workers,
                                         prefetch_factor=4, worker_init_fn=single_thread_worker)
    it = iter(loader)
    next(it)  # worker start-up is not throughput
    t = time.perf_counter()
    count = sum(1 for _ in it)
    return round(count / (time.perf_counter() - t), 2)


def main() -> None:
    import torch

    from sim2real.presets import preset
    from sim2real.data.datasets import TrainPairs, resolve_scenes
    from sim2real.data.real import RealImages
    from sim2real.threads import usable_cores

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="paper,small")
    ap.add_argument("--samples", type=int, default=30)
    ap.add_argument("--views", type=int, default=32, help="cached views rendered for the views-folder case")
    ap.add_argument("--max-workers", type=int, default=usable_cores())
    ap.add_argument("--target", type=float, default=20.0, help="iterations/s the loader must feed")
    args = ap.parse_args()
    torch.set_num_threads(1)
    result = {"benchmark": "train_data", "machine": f"{platform.machine()} {os.cpu_count()} cores",
              "usable_cores": usable_cores(), "torch": str(torch.__version__), "target_it_per_s": args.target,
              "presets": {}}
    with tempfile.TemporaryDirectory(prefix="bench_data_") as tmp:
        base = Path(tmp)
        for name in args.presets.split(","):
            cfg = preset(name).data
            scene, real, views = _inputs(base, cfg.height, cfg.width, args.views)
            entry = {"size": f"{cfg.height}x{cfg.width}"}
            for source, path in (("fresh_views", scene), ("cached_views", views)):
                ds = TrainPairs(resolve_scenes([path], cfg.height, cfg.width), RealImages(real), cfg, seed=0)
                s = _in_process(ds, args.samples)
                rates = {w: _loader_rate(ds, w, args.samples) for w in range(1, args.max_workers + 1)}
                entry[source] = {"s_per_sample": s, "workers_for_target": math.ceil(args.target * s["mean"]),
                                 "loader_samples_per_s": rates}
                print(json.dumps({name: {source: entry[source]}}), file=sys.stderr)
            result["presets"][name] = entry
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
