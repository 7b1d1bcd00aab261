"""Ray casting throughput of the G-buffer path at 256x512; prints JSON.

In process: rays/s of one process (median over views), views/s of a pool of 2 worker processes
(ray casting only, no files), and the peak memory of rendering one view (numpy allocations via tracemalloc; process max RSS).

End to end (``--e2e-views SMALL,LARGE``): the command ``sim2real render`` as a subprocess, run
``--repeats`` times at each of two view counts, alternating. The steady rate excludes the
start-up: views/s = (LARGE - SMALL) / (median wall(LARGE) - median wall(SMALL)); start-up =
median wall(SMALL) - SMALL / that rate (interpreter, imports, scene, workers; everything that
does not grow with the views). ``e2e_share_of_inprocess_2core`` compares the rate with twice the
one-process in-process rate (what two cores could do if rendering were all there was).
``e2e_rays_per_s_24_with_startup`` is the rate at 24 views with the start-up included.

Usage: python benchmarks/bench_raycast.py [--views 24] [--height 256] [--width 512]
       [--e2e-views 24,96] [--repeats 3] [--no-e2e]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

from sim2real.pool import WorkerPool
from sim2real.render.raycast import RayCaster, caster_setup
from sim2real.scene.procedural import generate_scene
from sim2real.scene.trajectory import sample_poses


def _render(caster, cam):
    return int(caster.render(cam).mask.sum())  # a number back, not the G-buffer: ray casting only


def end_to_end(scene_dir: Path, height: int, width: int, counts: tuple[int, int], repeats: int) -> dict:
    """Wall time of ``sim2real render`` subprocesses (see the module docstring)."""
    walls: dict[int, list[float]] = {n: [] for n in counts}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            for n in counts:
                out = Path(tmp) / f"views_{n}"
                cmd = [sys.executable, "-m", "sim2real.cli.main", "render", str(scene_dir), "--views", str(n),
                       "--height", str(height), "--width", str(width), "--out", str(out)]
                t = time.perf_counter()
                subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                walls[n].append(time.perf_counter() - t)
                shutil.rmtree(out)
    small, large = counts
    w_small, w_large = statistics.median(walls[small]), statistics.median(walls[large])
    rate = (large - small) / (w_large - w_small)
    return {
        "e2e_views": list(counts),
        "e2e_repeats": repeats,
        "e2e_wall_s": {str(n): [round(x, 3) for x in walls[n]] for n in counts},
        "e2e_views_per_s_excl_startup": rate,
        "e2e_startup_s": w_small - small / rate,
        "e2e_views_per_s_with_startup": {str(n): n / statistics.median(walls[n]) for n in counts},
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--e2e-views", default="24,96", help="SMALL,LARGE view counts of the end-to-end runs")
    ap.add_argument("--repeats", type=int, default=3, help="end-to-end runs per view count")
    ap.add_argument("--no-e2e", action="store_true", help="skip the end-to-end command")
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
    result["views_per_s_inprocess_1proc"] = 1.0 / statistics.median(times)
    with WorkerPool(2, caster_setup, (caster.geometry,)) as pool:
        list(pool.imap(_render, cams[:2]))  # build the scene in every worker first
        t = time.perf_counter()
        list(pool.imap(_render, cams))
        dt = time.perf_counter() - t
    result["views_per_s_pool_2proc"] = len(cams) / dt
    result["rays_per_s_pool_2proc"] = len(cams) * rays / dt
    if not args.no_e2e:
        counts = tuple(int(x) for x in args.e2e_views.split(","))
        with tempfile.TemporaryDirectory() as tmp:
            scene_dir = generate_scene(seed).save(Path(tmp) / "scene")
            result.update(end_to_end(scene_dir, args.height, args.width, counts, args.repeats))
        result["e2e_share_of_inprocess_2core"] = result["e2e_views_per_s_excl_startup"] / (2 * result["views_per_s_inprocess_1proc"])
        if 24 in counts:
            result["e2e_rays_per_s_24_with_startup"] = result["e2e_views_per_s_with_startup"]["24"] * rays
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
