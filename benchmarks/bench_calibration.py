"""Cost of the calibrated evaluation: ceiling and floor frames/s, and evaluation wall time with
and without the anchors on a run.

    python benchmarks/bench_calibration.py [--frames 30]
    python benchmarks/bench_calibration.py --run DEMO/run --scenes DEMO/scenes/sim_0 --real DEMO/real

Prints JSON. Frames/s are steady-state shading of G-buffers already ray cast (the evaluation
casts them once for all rows); building an appearance's solid textures is timed separately.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def anchor_rates(frames: int) -> dict:
    from sim2real.inference.anchors import Anchors
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.procedural import generate_scene
    from sim2real.scene.trajectory import make_trajectory

    scene = generate_scene(0)
    caster = RayCaster(scene)
    out = {}
    for h, w in ((128, 256), (256, 512)):
        traj = make_trajectory(caster, frames, h, w, 75.0, seed=0)
        gbs = [caster.render(c) for c in traj.cameras]
        a = Anchors(scene, seed=0, pool=frames + 1)
        t0 = time.perf_counter()
        a.ceiling(gbs[0], 0)
        build = time.perf_counter() - t0
        times = []
        for t, g in enumerate(gbs[1:], 1):
            t0 = time.perf_counter()
            a.ceiling(g, t)
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for t, g in enumerate(gbs[:5]):
            a.floor(g, t)  # a new appearance each: build + shade
        floor_new = (time.perf_counter() - t0) / 5
        out[f"{h}x{w}"] = {"ceiling_frames_per_s": 1.0 / float(np.median(times)),
                           "appearance_build_s": build - float(np.median(times)),
                           "floor_s_per_frame_with_new_appearance": floor_new}
    return out


def eval_time(run: str, scenes: list[str], real: str, extra: list[str], keep: str | None = None) -> float:
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "sim2real.cli.main", "evaluate", run, "--scenes", *scenes, "--real", real,
               "--out", keep or str(Path(d) / "e"), "--no-progress", "--views", "32", *extra]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--run")
    p.add_argument("--scenes", nargs="+")
    p.add_argument("--real")
    p.add_argument("--trajectory", help="the demo's trajectory file (default: a generated path)")
    p.add_argument("--keep", help="write the calibrated evaluation here (a new folder)")
    args = p.parse_args()
    res = {"anchors": anchor_rates(args.frames)}
    if args.run:
        # the segmenter cache is warm after the first call: time both with it warm
        traj = ["--trajectory", args.trajectory] if args.trajectory else []
        first = eval_time(args.run, args.scenes, args.real, ["--no-anchors", *traj])
        res["evaluate_s"] = {"with_anchors": eval_time(args.run, args.scenes, args.real, traj, args.keep),
                             "without_anchors": eval_time(args.run, args.scenes, args.real, ["--no-anchors", *traj]),
                             "first_call_training_the_segmenters": first}
        res["evaluate_s"]["ratio"] = res["evaluate_s"]["with_anchors"] / res["evaluate_s"]["without_anchors"]
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
