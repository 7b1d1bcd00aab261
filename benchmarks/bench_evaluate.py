"""Seconds of each stage of ``sim2real evaluate`` on a demo's output, and of each measure; prints JSON.

    sim2real demo --out DEMO                     # once: the run, scenes, real folder, trajectory
    python benchmarks/bench_evaluate.py --demo DEMO [--fresh-segmenters] [--against OTHER.json]

Evaluates ``DEMO/run`` as the demo does (the settings of ``DEMO/evaluation/metrics.json``: 32
views, the 100-frame trajectory, 200 segmenter steps) into a temporary folder. Reports, per
stage (views, realism, dice, consistency, total), the wall seconds and the CPU seconds of this
process (all its threads: on a shared core the CPU seconds are the steadier figure), and per
measure the wall seconds spent inside the functions that compute it: the C2ST realism test,
the segmenters (training or loading) and their Dice, the odometry, the ORB-k and OF metrics of
every row, the ceiling's and floor's rendering, the ray casting and the model's translation.
A function that a version of the code does not have is left out, so that the same script times
an older checkout (run it with ``PYTHONPATH=OLD/src``).

``--fresh-segmenters`` points ``SIM2REAL_CACHE`` at an empty folder, so the segmenters train
(the fresh-machine demo); by default the cache is used. ``--save FILE`` keeps the evaluation's
figures (metrics.json without timings and paths); ``--against FILE`` compares the figures with
such a file and lists every value that differs.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import dataclasses
import functools
import importlib
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

# (module, attribute, measure): wrapped with a timer when the module has the attribute. Nested
# calls count in each measure they pass through.
PROBES = [
    ("sim2real.inference.realism", "c2st", "c2st"),
    ("sim2real.inference.realism", "proxy_colour_texture_distance", "proxy"),
    ("sim2real.inference.stages", "segmenters", "segmenters"),
    ("sim2real.inference.stages", "dice_of", "dice_of"),
    ("sim2real.inference.stages", "odometry", "odometry"),
    ("sim2real.inference.stages", "sequence_row", "of_orb_revisit"),
    ("sim2real.inference.stages", "sequence_rows", "of_orb_revisit"),
    ("sim2real.inference.stages", "iter_gbuffers", "ray_casting"),
    ("sim2real.inference.stages", "gt_flow", "ground_truth_flow"),
    ("sim2real.inference.stages", "reference_rendering", "a_ref"),
]
METHOD_PROBES = [
    ("sim2real.inference.anchors", "Anchors", "ceiling", "anchors_render"),
    ("sim2real.inference.anchors", "Anchors", "floor", "anchors_render"),
    ("sim2real.inference.anchors", "Anchors", "ceilings", "anchors_render"),
    ("sim2real.inference.anchors", "Anchors", "floors", "anchors_render"),
    ("sim2real.inference.model", "TrainedModel", "translate_views", "translate"),
    ("sim2real.inference.model", "FrameSequence", "translate", "translate"),
]
STAGES = ("views_stage", "realism_stage", "segmentation_stage", "consistency_stage")


def _timer(fn, measure: str, wall: dict, cpu: dict, depth: dict):
    @functools.wraps(fn)
    def wrapped(*a, **k):
        depth[measure] = depth.get(measure, 0) + 1
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            result = fn(*a, **k)
            if hasattr(result, "__next__"):  # a generator: time its consumption too
                result = list(result)
            return result
        finally:
            depth[measure] -= 1
            if depth[measure] == 0:  # outermost call only (recursion, nested wrappers)
                wall[measure] = wall.get(measure, 0.0) + time.perf_counter() - t0
                cpu[measure] = cpu.get(measure, 0.0) + time.process_time() - c0
    return wrapped


def install_probes(wall: dict, cpu: dict) -> list[str]:
    depth: dict = {}
    found = []
    for mod, attr, measure in PROBES:
        m = importlib.import_module(mod)
        if hasattr(m, attr):
            setattr(m, attr, _timer(getattr(m, attr), measure, wall, cpu, depth))
            found.append(f"{mod}.{attr}")
    for mod, cls, meth, measure in METHOD_PROBES:
        c = getattr(importlib.import_module(mod), cls, None)
        if c is not None and hasattr(c, meth):
            setattr(c, meth, _timer(getattr(c, meth), measure, wall, cpu, depth))
            found.append(f"{mod}.{cls}.{meth}")
    ev = importlib.import_module("sim2real.inference.evaluate")
    for name in STAGES:  # CPU seconds of the stages (the evaluation itself records their wall time)
        setattr(ev, name, _timer(getattr(ev, name), "stage_" + name, {}, cpu, depth))
    return found


FIGURE_SKIP = {"seconds", "run", "inputs", "dice_info", "fid_kid"}


def figures(metrics: dict) -> dict:
    """metrics.json without timings, paths and cache locations: what must not change."""
    out = {k: v for k, v in metrics.items() if k not in FIGURE_SKIP}
    out["realism"] = {n: {k: v for k, v in m.items() if k != "seconds"} for n, m in metrics["realism"].items()}
    out["per_scene"] = {n: {k: v for k, v in sc.items() if k != "trajectory"} for n, sc in metrics["per_scene"].items()}
    out["dice_rows"] = {r: d for r, d in metrics["dice_info"]["rows"].items()}
    return out


def differences(a, b, path="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'new' if k in a else 'reference'}")
            else:
                out += differences(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: length {len(a)} vs {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", required=True, help="output folder of 'sim2real demo'")
    ap.add_argument("--fresh-segmenters", action="store_true", help="train the segmenters in an empty cache")
    ap.add_argument("--save", default=None, help="write the evaluation's figures to this JSON file")
    ap.add_argument("--against", default=None, help="compare the figures with this file (from --save)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads of the evaluation's jobs (default: one per core of this process's share)")
    ap.add_argument("--profile", default=None, help="also write cProfile statistics of the evaluation to this file")
    args = ap.parse_args()

    demo = Path(args.demo)
    old = json.loads((demo / "evaluation" / "metrics.json").read_text())
    tmp = tempfile.mkdtemp(prefix="bench_evaluate_")
    if args.fresh_segmenters:
        os.environ["SIM2REAL_CACHE"] = str(Path(tmp) / "cache")
    wall: dict = {}
    cpu: dict = {}
    probes = install_probes(wall, cpu)
    if args.threads:  # as on a machine with that many cores (the ray casting keeps its own rule)
        for mod, attr, fn in (("sim2real.inference.jobs", "worker_count", lambda jobs=None: args.threads),
                              ("sim2real.inference.dice", "usable_cores", lambda: args.threads)):
            m = importlib.import_module(mod)
            if hasattr(m, attr):
                setattr(m, attr, fn)
    ev = importlib.import_module("sim2real.inference.evaluate")
    known = {f.name for f in dataclasses.fields(ev.EvalSettings)}
    s = ev.EvalSettings(**{k: v for k, v in old["settings"].items() if k in known})
    scenes = [sc["scene_dir"] for sc in old["inputs"]["scenes"]]
    trajs = [sc["trajectory"] for sc in old["inputs"]["scenes"]]
    c0 = time.process_time()
    prof = cProfile.Profile() if args.profile else contextlib.nullcontext()
    with contextlib.redirect_stderr(open(os.devnull, "w")), prof:
        m = ev.evaluate(demo / "run", scenes, demo / "real", Path(tmp) / "evaluation", trajectories=trajs, settings=s,
                        device=args.device, progress=False)
    total_cpu = time.process_time() - c0
    if args.profile:
        prof.dump_stats(args.profile)
    stages = {k: {"wall_s": round(v, 2)} for k, v in m["seconds"].items()}
    for name, key in zip(STAGES, ("views", "realism", "dice", "consistency")):
        if key in stages:
            stages[key]["cpu_s"] = round(cpu.get("stage_" + name, float("nan")), 2)
    stages["total"]["cpu_s"] = round(total_cpu, 2)
    out = {
        "demo": str(demo.resolve()),
        "settings": {k: old["settings"][k] for k in ("views", "frames", "seg_iterations", "seg_seeds", "c2st_steps",
                                                      "odometry_pairs", "orb_max_k")},
        "segmenters": "trained (empty cache)" if args.fresh_segmenters else "cache",
        "stages": stages,
        "measures_wall_s": {k: round(v, 2) for k, v in sorted(wall.items())},
        "measures_cpu_s": {k: round(v, 2) for k, v in sorted(cpu.items()) if not k.startswith("stage_")},
        "threads": args.threads,
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "probes": probes,
    }
    figs = figures(m)
    if args.save:
        Path(args.save).write_text(json.dumps(figs, sort_keys=True))
    if args.against:
        diff = differences(figs, json.loads(Path(args.against).read_text()))
        out["figures_differ"] = len(diff)
        out["differences"] = diff[:40]
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
