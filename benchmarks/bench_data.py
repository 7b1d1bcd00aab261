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
``pool_build``     building a view pool, per view: its pose, ray casting, the write into the
                   memory-mapped file (data/viewpool.py; once per scene, up front)
``pool_read``      reading one pooled view back from the memory-mapped file and widening it
``sample``         one whole ``TrainPairs`` sample (two views, redraws of j below the overlap,
                   a real crop): fresh poses, the view pool (the default of the GPU presets),
                   or a views folder read from disk
=================  ==============================================================================

Whole samples, three ways for a bare scene folder: ``fresh`` (``data.view_pool=0``: two poses
ray-cast per sample), ``pooled_cached`` (the pool's file built; every later epoch and run) and
``pooled_first_epoch`` (the same plus the pool's build shared by the samples of its first epoch:
N views make N/2 pairs, so each first-epoch sample carries two views' build). The pool's views
are read with the file in the page cache (``pooled_cached``) and again after evicting it
(``pooled_cold``, ``posix_fadvise(DONTNEED)``: every view read from disk). ``disk`` gives the bytes
per pooled view and per pool of ``--pool-views`` and of the presets' 3,000.

``worker_pair_s`` sums a worker's stages of one pair (2 x pose and raycast; correspondences;
real; pack; collate); ``per_core_samples_per_s`` is ``1 / sample`` median; ``host_16_cores_samples_per_s``
extrapolates it linearly to 15 loader workers (16 cores, one kept for the training process), the
rule ``sim2real.threads.worker_count`` applies. ``bytes_per_sample`` is what crosses shared memory
and the host-to-device copy.

Usage: python benchmarks/bench_data.py [--samples 20] [--pool-views 40] [--device cpu|cuda] [--loader-workers N]
"""

from __future__ import annotations

import argparse
import dataclasses
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

import sim2real.data.viewpool
from sim2real.data.datasets import StepSampler, TrainPairs, resolve_scenes
from sim2real.data.real import RealImages, load_rgb, random_resized_crop
from sim2real.data.tensors import compact, complete_on_device, view_inputs, widen
from sim2real.data.viewpool import GBUFFERS, attach_view_pools, bytes_per_view, open_pool
from sim2real.data.views import write_views_manifest
from sim2real.engine.loader import make_loader
from sim2real.presets import POOL_VIEWS, preset
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering
from sim2real.render.warp import correspondences
from sim2real.scene.procedural import generate_scene
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import sample_poses
from sim2real.threads import usable_cores

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


def rates(times: list[float], extra_s: float = 0.0) -> dict:
    """Per-core and 16-core figures of per-sample CPU seconds ``times`` (plus ``extra_s`` each)."""
    med, mean = statistics.median(times) + extra_s, statistics.mean(times) + extra_s
    return {"cpu_s_per_sample_median": round(med, 4), "cpu_s_per_sample_mean": round(mean, 4),
            "per_core_samples_per_s": round(1 / med, 2),
            f"host_{HOST_CORES}_cores_samples_per_s": round((HOST_CORES - 1) / mean, 1)}


def sample_times(sources, real: Path, cfg, n: int, before_each=None) -> list[float]:
    ds = TrainPairs(sources, RealImages(real), cfg, seed=0)
    ds[0]
    times = []
    for s in range(1, n + 1):
        if before_each is not None:
            before_each()
        t = time.process_time()
        ds[s]
        times.append(time.process_time() - t)
    return times


def whole_samples(path: Path, real: Path, cfg, n: int) -> dict:
    return rates(sample_times(resolve_scenes([path], cfg.height, cfg.width), real, cfg, n))


def evict(path: Path) -> None:
    """Drop ``path``'s clean pages from the page cache: the next reads come from the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def pooled(scene: Path, real: Path, cfg, n: int, views: int) -> dict:
    """Build a view pool of ``views`` views in this process (CPU time per view), then time samples
    drawn from it: warm, cold, and with the build shared by the first epoch."""
    cfg = dataclasses.replace(cfg, view_pool=views)
    s = Scene.load(scene)
    t = time.process_time()
    pool = open_pool(scene, s, cfg, seed=0, progress=False)
    build_s = (time.process_time() - t) / views
    sources = resolve_scenes([scene], cfg.height, cfg.width)
    attach_view_pools(sources, cfg, 0, progress=False)
    read_s = median_s(lambda: pool.view(int(np.random.default_rng().integers(views))), n)
    warm = sample_times(sources, real, cfg, n)
    file = pool.folder / GBUFFERS
    cold = sample_times(sources, real, cfg, n, before_each=lambda: evict(file))
    size = sum(p.stat().st_size for p in pool.folder.iterdir())
    return {"views": views, "pool_build_s_per_view": round(build_s, 5), "pool_read_s_per_view": round(read_s, 5),
            "pooled_cached": rates(warm), "pooled_cold": rates(cold),
            "pooled_first_epoch": rates(warm, extra_s=2 * build_s),
            "disk": {"bytes_per_view": bytes_per_view(cfg.height, cfg.width),
                     "measured_bytes_per_view": round(size / views),
                     f"bytes_per_pool_of_{views}": size,
                     f"bytes_per_pool_of_{POOL_VIEWS}": POOL_VIEWS * bytes_per_view(cfg.height, cfg.width),
                     f"GiB_per_pool_of_{POOL_VIEWS}": round(POOL_VIEWS * bytes_per_view(cfg.height, cfg.width) / 2**30, 2),
                     "views_folder_bytes_per_view": None}}


def loader_rate(path: Path, real: Path, cfg, workers: int, n: int) -> float:
    ds = TrainPairs(resolve_scenes([path], cfg.height, cfg.width), RealImages(real), cfg, seed=0)
    loader = make_loader(ds, StepSampler(0, n + 1), workers, pin_memory=False, announce=True)  # the trainer's
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
    ap.add_argument("--pool-views", type=int, default=40, help="views of the view pool that is built and timed")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = preset(args.preset).data
    sim2real.data.viewpool.worker_count = lambda jobs=None, reserve=0: 1  # built in this process: its CPU time counts
    result = {"benchmark": "train_data", "preset": args.preset, "size": f"{cfg.height}x{cfg.width}",
              "machine": f"{platform.machine()} {os.cpu_count()} cores", "usable_cores": usable_cores(),
              "torch": str(torch.__version__), "device": args.device, "real_frames": "854x480 JPEG"}
    with tempfile.TemporaryDirectory(prefix="bench_data_") as tmp, threadpool_limits(1):
        os.environ["SIM2REAL_CACHE"] = str(Path(tmp) / "cache")  # the pools it builds go with it, not into the user's cache
        scene, real, views = make_inputs(Path(tmp), cfg.height, cfg.width, max(8, args.samples))
        result["stages_s"] = stages(scene, real, cfg, args.samples, torch.device(args.device))
        print(json.dumps(result["stages_s"]), file=sys.stderr)
        result["fresh_views"] = whole_samples(scene, real, cfg, args.samples)
        print(json.dumps(result["fresh_views"]), file=sys.stderr)
        result["view_pool"] = pooled(scene, real, cfg, args.samples, args.pool_views)
        result["view_pool"]["disk"]["views_folder_bytes_per_view"] = round(
            statistics.mean(p.stat().st_size for p in views.glob("view_*.npz")))
        result["cached_views"] = whole_samples(views, real, cfg, args.samples)
        fresh = result["fresh_views"]["per_core_samples_per_s"]
        result["pooled_vs_fresh_per_core"] = {k: round(result["view_pool"][k]["per_core_samples_per_s"] / fresh, 2)
                                              for k in ("pooled_cached", "pooled_first_epoch", "pooled_cold")}
        if args.loader_workers:
            result["loader_samples_per_s"] = {"workers": args.loader_workers,
                                              "fresh_views": loader_rate(scene, real, cfg, args.loader_workers,
                                                                         args.samples)}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
