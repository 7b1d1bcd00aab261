"""Training-data throughput per core, stage by stage, for a paper-size (256x512) view pair; prints JSON.

Run it pinned to one core for per-core figures: ``taskset -c 1 python benchmarks/bench_data.py``.
Every stage runs in this process on one thread, as a DataLoader worker runs it, on a procedural
scene and real frames of 854x480 (JPEG, quality 90: a laparoscope's frame size and format).
Times are CPU seconds of this process (``time.process_time``), not wall time: on a shared
machine they stay the cost of the work while other processes take turns on the core.

=================  ==============================================================================
stage              what is timed (median over ``--samples``)
=================  ==============================================================================
``pose``           drawing a random camera pose (trajectory.sample_poses: a few probe rays)
``raycast``        ray casting one view (Embree, G-buffer)
``a_ref_numpy``    the reference rendering of one view in a worker (as before; now on the device)
``correspondences``  uv and visibility of view i in view j (the warping masks)
``real``           decoding a real frame and its random resized crop
``pack``           the sample's tensors in their transfer dtypes (view_inputs + compact)
``collate``        default_collate of one sample (the loader's batch of 1)
``to_device``      copy to ``--device``, widen and render both a_ref there (pinned source on CUDA)
``sample``         one whole ``TrainPairs`` sample (two views, redraws of j below the overlap,
                   a real crop), fresh poses or cached views (a views folder read from disk)
=================  ==============================================================================

``worker_pair_s`` sums a worker's stages of one pair (2 x pose and raycast; correspondences;
real; pack; collate); ``per_core_samples_per_s`` is ``1 / sample`` median; ``host_16_cores_samples_per_s``
extrapolates it linearly to 15 loader workers (16 cores, one kept for the training process), the
rule ``sim2real.threads.worker_count`` applies. ``bytes_per_sample`` is what crosses shared memory
and the host-to-device copy.

Usage: python benchmarks/bench_data.py [--samples 20] [--device cpu|cuda] [--loader-workers N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from threadpoolctl import threadpool_limits
from torch.utils.data import default_collate

from sim2real.data.datasets import StepSampler, TrainPairs, resolve_scenes
from sim2real.data.real import RealImages, load_rgb, random_resized_crop
from sim2real.data.tensors import compact, complete_on_device, view_inputs, widen
from sim2real.data.views import write_views_manifest
from sim2real.presets import preset
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering
from sim2real.render.warp import correspondences
from sim2real.scene.procedural import generate_scene
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import sample_poses
from sim2real.threads import single_thread_worker, usable_cores

HOST_CORES = 16


def make_inputs(base: Path, height: int, width: int, views: int) -> tuple[Path, Path, Path]:
    scene = base / "scene"
    generate_scene(0).save(scene)
    real = base / "real"
    real.mkdir()
    rng = np.random.default_rng(0)
    for k in range(6):  # textured, not flat: JPEG decoding costs what it costs on real frames
        small = rng.integers(0, 256, (60, 107, 3), dtype=np.uint8)
        im = Image.fromarray(small).resize((854, 480), Image.BICUBIC)
        noise = rng.normal(0, 12, (480, 854, 3))
        Image.fromarray(np.clip(np.asarray(im) + noise, 0, 255).astype(np.uint8)).save(real / f"r{k}.jpg", quality=90)
    folder = base / "views"
    s = Scene.load(scene)
    caster = RayCaster(s)
    for k, cam in enumerate(sample_poses(caster, views, height, width, 75.0, seed=7)):
        caster.render(cam).save(folder / f"view_{k:05d}.npz", durable=False)
    write_views_manifest(folder, s.name, scene, views)
    return scene, real, folder


def median_s(fn, n: int) -> float:
    """Median CPU seconds of ``fn()`` over ``n`` calls after one warm-up call."""
    fn()  # warm-up (caches, first-call imports)
    times = []
    for _ in range(n):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return statistics.median(times)


def stages(scene: Path, real: Path, cfg, n: int, device: torch.device) -> dict:
    caster = RayCaster(Scene.load(scene))
    h, w = cfg.height, cfg.width
    cams = sample_poses(caster, 2, h, w, cfg.fov_x_deg, seed=3)
    gi, gj = caster.render(cams[0]), caster.render(cams[1])
    files = sorted(real.glob("*.jpg"))
    rng = np.random.default_rng(0)
    out = {
        "pose": median_s(lambda: sample_poses(caster, 1, h, w, cfg.fov_x_deg, seed=int(rng.integers(1 << 30))), n),
        "raycast": median_s(lambda: caster.render(cams[0]), n),
        "a_ref_numpy": median_s(lambda: reference_rendering(gi), n),
        "correspondences": median_s(lambda: correspondences(gi, gj), n),
        "real": median_s(lambda: random_resized_crop(load_rgb(files[int(rng.integers(len(files)))]), h, w,
                                                     cfg.real_scale_min, cfg.real_scale_max, rng), n),
    }
    uv, vis = correspondences(gi, gj)
    crop = random_resized_crop(load_rgb(files[0]), h, w, 1.0, 1.2, rng)
    real_t = torch.from_numpy((crop.astype(np.float32).transpose(2, 0, 1) / 127.5) - 1.0)

    def pack():
        s = {"step": torch.tensor(0), "scene": torch.tensor(0), "uv_ij": torch.from_numpy(uv),
             "visible_ij": torch.from_numpy(vis), "real": real_t}
        for tag, g in (("i", gi), ("j", gj)):
            s.update({k: v[0] for k, v in view_inputs([g], tag, len(gi.classes)).items()})
        return compact(s)

    out["pack"] = median_s(pack, n)
    sample = pack()
    out["collate"] = median_s(lambda: default_collate([sample]), n)
    batch = default_collate([sample])
    if device.type == "cuda":
        batch = {k: v.pin_memory() for k, v in batch.items()}

    def to_device():
        complete_on_device(widen({k: v.to(device, non_blocking=True) for k, v in batch.items()}))
        if device.type == "cuda":
            torch.cuda.synchronize()

    out["to_device"] = median_s(to_device, n)
    out = {k: round(v, 5) for k, v in out.items()}
    out["worker_pair_s"] = round(2 * (out["pose"] + out["raycast"]) + out["correspondences"] + out["real"]
                                 + out["pack"] + out["collate"], 5)
    out["bytes_per_sample"] = int(sum(v.numel() * v.element_size() for v in sample.values()))
    return out


def whole_samples(path: Path, real: Path, cfg, n: int) -> dict:
    ds = TrainPairs(resolve_scenes([path], cfg.height, cfg.width), RealImages(real), cfg, seed=0)
    ds[0]
    times = []
    for s in range(1, n + 1):
        t = time.process_time()
        ds[s]
        times.append(time.process_time() - t)
    med = statistics.median(times)
    return {"cpu_s_per_sample_median": round(med, 4), "cpu_s_per_sample_mean": round(statistics.mean(times), 4),
            "per_core_samples_per_s": round(1 / med, 2),
            f"host_{HOST_CORES}_cores_samples_per_s": round((HOST_CORES - 1) / statistics.mean(times), 1)}


def loader_rate(path: Path, real: Path, cfg, workers: int, n: int) -> float:
    ds = TrainPairs(resolve_scenes([path], cfg.height, cfg.width), RealImages(real), cfg, seed=0)
    loader = torch.utils.data.DataLoader(ds, batch_size=1, sampler=StepSampler(0, n + 1), num_workers=workers,
                                         prefetch_factor=2, worker_init_fn=single_thread_worker)
    it = iter(loader)
    next(it)  # worker start-up is not throughput
    t = time.perf_counter()
    count = sum(1 for _ in it)
    return round(count / (time.perf_counter() - t), 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--samples", type=int, default=20)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--loader-workers", type=int, default=0, help="also time a DataLoader with this many workers")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = preset(args.preset).data
    result = {"benchmark": "train_data", "preset": args.preset, "size": f"{cfg.height}x{cfg.width}",
              "machine": f"{platform.machine()} {os.cpu_count()} cores", "usable_cores": usable_cores(),
              "torch": str(torch.__version__), "device": args.device, "real_frames": "854x480 JPEG"}
    with tempfile.TemporaryDirectory(prefix="bench_data_") as tmp, threadpool_limits(1):
        scene, real, views = make_inputs(Path(tmp), cfg.height, cfg.width, max(8, args.samples))
        result["stages_s"] = stages(scene, real, cfg, args.samples, torch.device(args.device))
        print(json.dumps(result["stages_s"]), file=sys.stderr)
        result["fresh_views"] = whole_samples(scene, real, cfg, args.samples)
        result["cached_views"] = whole_samples(views, real, cfg, args.samples)
        if args.loader_workers:
            result["loader_samples_per_s"] = {"workers": args.loader_workers,
                                              "fresh_views": loader_rate(scene, real, cfg, args.loader_workers,
                                                                         args.samples)}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
