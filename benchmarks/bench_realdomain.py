"""Throughput of the stand-in real domain (sim2real.realdomain) at 256x512; prints JSON.

* ``frames_per_s_1proc``: one process, warm (materials built), ray casting + shading + PNG
  writing of image and label, median over frames;
* ``frames_per_s_2proc_pool``: the process pool of ``make_real_domain`` with 2 warm workers,
  median over ``--repeats`` batches of ``--frames`` frames;
* ``frames_per_s_end_to_end_2proc``: one whole ``make_real_domain`` call (pool start, per-worker
  material building, pose sampling, writing) for ``--e2e-images`` images.
Also the breakdown of one frame (ray casting vs shading) and the one-off material build time.
Usage: python benchmarks/bench_realdomain.py [--frames 12] [--repeats 3] [--e2e-images 24]
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

from sim2real import realdomain as rd
from sim2real.pool import WorkerPool
from sim2real.realdomain.writer import WorkerScenes, render_job
from sim2real.render.raycast import RayCaster
from sim2real.scene.procedural import generate_scene
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import sample_poses


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--e2e-images", type=int, default=24)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--width", type=int, default=512)
    args = ap.parse_args()
    h, w = args.height, args.width
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene_dir = str(generate_scene(1000).save(tmp / "real_1000"))
        scene = Scene.load(scene_dir)
        caster = RayCaster(scene)
        cams = sample_poses(caster, args.frames, h, w, 75.0, seed=1)
        app = rd.Appearance.sample(rd.derive_seed(0, 11, 0))
        opt = rd.RenderOptions(height=h, width=w)

        # One-off cost: building every object's solid-texture fields.
        material = rd.SceneMaterial(scene, app)
        t = time.perf_counter()
        g0 = caster.render(cams[0])
        rd.render_frame(g0, material, opt, seed=0)
        build_s = time.perf_counter() - t

        jobs = [(0, cam, i, str(tmp / "f" / f"{i}.png"), str(tmp / "l" / f"{i}.png")) for i, cam in enumerate(cams)]
        state = WorkerScenes([scene_dir], [app.to_json()], opt.to_json())
        state.scenes[0] = (caster, material)
        single, ray, shade = [], [], []
        for job in jobs:
            t = time.perf_counter()
            render_job(state, job)
            single.append(time.perf_counter() - t)
            t = time.perf_counter()
            g = caster.render(job[1])
            t1 = time.perf_counter()
            rd.render_frame(g, material, opt, seed=0)
            ray.append(t1 - t)
            shade.append(time.perf_counter() - t1)

        result = {
            "benchmark": "realdomain_frames",
            "machine": f"{platform.machine()} {os.cpu_count()} cores",
            "height": h,
            "width": w,
            "frames": args.frames,
            "repeats": args.repeats,
            "material_build_s": build_s,
            "median_ms_raycast": 1e3 * statistics.median(ray),
            "median_ms_shading": 1e3 * statistics.median(shade),
            "median_ms_per_frame_1proc": 1e3 * statistics.median(single),
            "frames_per_s_1proc": 1.0 / statistics.median(single),
        }
        setup_args = ([scene_dir], [app.to_json()], opt.to_json())
        with WorkerPool(2, WorkerScenes, setup_args) as pool:
            list(pool.imap(render_job, jobs[:2]))  # build the materials in every worker
            rates = []
            for _ in range(args.repeats):
                t = time.perf_counter()
                list(pool.imap(render_job, jobs))
                rates.append(len(jobs) / (time.perf_counter() - t))
        result["frames_per_s_2proc_pool"] = statistics.median(rates)
        t = time.perf_counter()
        rd.make_real_domain([scene_dir], tmp / "e2e", images=args.e2e_images, seed=0, height=h, width=w,
                            workers=2, progress=False)
        result["e2e_images"] = args.e2e_images
        result["frames_per_s_end_to_end_2proc"] = args.e2e_images / (time.perf_counter() - t)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
