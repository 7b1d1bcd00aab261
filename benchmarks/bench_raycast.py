"""Ray casting throughput of the G-buffer path at 256x512; prints JSON.

rays/s of one process (median over views), views/s with 1 and 2 worker processes, and the
peak memory of rendering one view (numpy allocations via tracemalloc; process max RSS).
Usage: python benchmarks/bench_raycast.py [--views 24] [--height 256] [--width 512]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import resource
import statistics
import time
import tracemalloc

from sim2real.render.raycast import RayCaster
from sim2real.scene.procedural import generate_scene
from sim2real.scene.trajectory import sample_poses
from sim2real.threads import single_thread_worker

_W = {}


def _init(seed):
    single_thread_worker()
    _W["c"] = RayCaster(generate_scene(seed))


def _render(cam):
    return int(_W["c"].render(cam).mask.sum())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--width", type=int, default=512)
    args = ap.parse_args()
    seed = 0
    caster = RayCaster(generate_scene(seed))
    cams = sample_poses(caster, args.views, args.height, args.width, 75.0, seed=1)
    caster.render(cams[0])  # warm-up (direction cache, page faults)
    times = []
    for cam in cams:
        t = time.perf_counter()
        caster.render(cam)
        times.append(time.perf_counter() - t)
    rays = args.height * args.width
    tracemalloc.start()
    caster.render(cams[0])
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    result = {
        "benchmark": "raycast_gbuffer",
        "machine": f"{platform.machine()} {os.cpu_count()} cores",
        "height": args.height,
        "width": args.width,
        "views": args.views,
        "median_ms_per_view": 1e3 * statistics.median(times),
        "rays_per_s_1proc": rays / statistics.median(times),
        "peak_numpy_mb_per_view": peak / 2**20,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    ctx = mp.get_context("spawn")
    for workers in (1, 2):
        with ctx.Pool(workers, initializer=_init, initargs=(seed,)) as pool:
            pool.map(_render, cams[:workers])  # build the scene in every worker first
            t = time.perf_counter()
            pool.map(_render, cams, chunksize=1)
            dt = time.perf_counter() - t
        result[f"views_per_s_{workers}proc"] = len(cams) / dt
        result[f"rays_per_s_{workers}proc_pool"] = len(cams) * rays / dt
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
