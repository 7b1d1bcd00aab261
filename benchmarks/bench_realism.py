"""Validation of the weight-free realism measures (``sim2real.metrics.twosample``): do they rank a
ladder of known defects correctly, how much do they move over seeds, and what do they cost?

Stand-in domain (the truth is known): the demo's data (``make_embedded_data``, seed 0, the demo's
training size 128x256), ``--views`` random views of its first scene rendered as the ceiling, the
floor, a_ref, and the ceiling blurred (1.5 px), with drawn dark lines, and with bright specks
(``sim2real.metrics.perturb``); the real images split in halves, a reference half that every
row is compared with and a held-out half (the ``real_held_out`` row, the null).

The user's own footage (``--real-footage DIR``, optional; frames of a real laparoscopic video):
its frames resized to 128x256, split in a reference half and a held-out half, and the held-out
half blurred, lined and specked; ``--other-footage DIR`` adds frames of another real domain as a
row.

Each measure is computed with ``--seeds`` seeds (the C2ST's split and training, the random
network's weights); the JSON gives each row's mean, min and max over the seeds, whether the
ranking holds (``real_held_out`` best, the ceiling next on the stand-in, every defect worse than
both) at every seed, and the wall time of one call per measure.

    python benchmarks/bench_realism.py --data /tmp/realism_data [--real-footage DIR] [--views 64]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from sim2real.data.real import list_images, load_rgb
from sim2real.inference.anchors import Anchors, stand_in_options
from sim2real.inference.realimages import find_real, fit_image, to_nchw
from sim2real.metrics.perturb import blurred, lined, specked
from sim2real.metrics.realism import proxy_colour_texture_distance
from sim2real.metrics.twosample import RANDOM_NET_SEED, c2st, random_kid
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import sample_poses

H, W, FOV = 128, 256, 75.0
DEFECTS = ("blurred", "lined", "specked")


def score(rows: dict[str, list], reference: list, seeds: int) -> dict:
    out: dict = {"c2st": {}, "c2st_auc": {}, "random_kid": {}, "proxy": {}}
    seconds: dict = {}
    cpu: dict = {}
    for row, frames in rows.items():
        for name in out:
            out[name][row] = []
        for s in range(seeds):
            t, tc = time.perf_counter(), time.process_time()
            c = c2st(frames, reference, seed=s)
            seconds.setdefault("c2st", []).append(time.perf_counter() - t)
            cpu.setdefault("c2st", []).append(time.process_time() - tc)
            out["c2st"][row].append(c["accuracy"])
            out["c2st_auc"][row].append(c["auc"])
            t, tc = time.perf_counter(), time.process_time()
            out["random_kid"][row].append(random_kid(frames, reference, seed=RANDOM_NET_SEED + s))
            seconds.setdefault("random_kid", []).append(time.perf_counter() - t)
            cpu.setdefault("random_kid", []).append(time.process_time() - tc)
        t = time.perf_counter()
        p = proxy_colour_texture_distance(to_nchw(frames), to_nchw(reference))["proxy_colour_texture_distance"]
        seconds.setdefault("proxy", []).append(time.perf_counter() - t)
        out["proxy"][row] = [p] * seeds
    result = {}
    for name, per_row in out.items():
        vals = np.array([per_row[r] for r in rows])  # rows x seeds
        result[name] = {"better": "lower", "rows": {r: {"mean": float(np.mean(v)), "min": float(np.min(v)),
                                                         "max": float(np.max(v)), "per_seed": [float(x) for x in v]}
                                                     for r, v in zip(rows, vals)}}
        result[name]["ranking"] = _ranking(list(rows), vals)
    return {"measures": result, "seconds_per_call_median": {k: float(np.median(v)) for k, v in seconds.items()},
            "cpu_seconds_per_call_median": {k: float(np.median(v)) for k, v in cpu.items()},
            "frames_per_set": {r: len(f) for r, f in rows.items()}, "reference_frames": len(reference)}


def _ranking(names: list[str], vals: np.ndarray) -> dict:
    """Whether the null row is best and every defect row worse than the clean rows, per seed. The
    floor is no per-frame defect (each of its frames is a stand-in frame): it is left out."""
    idx = {n: i for i, n in enumerate(names)}
    clean = [n for n in ("real_held_out", "ceiling") if n in idx]
    bad = [n for n in names if n not in clean and n != "floor"]
    per_seed = []
    for s in range(vals.shape[1]):
        v = vals[:, s]
        ok = all(v[idx[b]] > max(v[idx[c]] for c in clean) for b in bad)
        if "ceiling" in idx:
            ok = ok and v[idx["real_held_out"]] <= v[idx["ceiling"]]
        per_seed.append(bool(ok))
    gaps = {b: float(np.mean(vals[idx[b]]) - max(np.mean(vals[idx[c]]) for c in clean)) for b in bad}
    spread = float(max(np.ptp(vals[i]) for i in range(len(names))))
    return {"holds_per_seed": per_seed, "smallest_gap_to_clean": min(gaps.values()) if gaps else None,
            "gap_per_row": gaps, "largest_seed_spread": spread}


def defects(frames: list, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    return {"blurred": [blurred(f) for f in frames], "lined": [lined(f, rng) for f in frames],
            "specked": [specked(f, rng) for f in frames]}


def halves(frames: list, seed: int) -> tuple[list, list]:
    perm = np.random.default_rng(seed).permutation(len(frames))
    k = len(frames) // 2
    return [frames[i] for i in perm[:k]], [frames[i] for i in perm[k:]]


def stand_in(data: Path, views: int, real_images: int, seeds: int) -> dict:
    from sim2real.data.embedded import make_embedded_data

    if not (data / "real" / "manifest.json").is_file():
        make_embedded_data(data, 0, 1, real_images, H, W, say=lambda m: print(f"data: {m}", file=sys.stderr))
    scene = Scene.load(data / "scenes" / "sim_0")
    caster = RayCaster(scene)
    opts, _ = stand_in_options(data / "real" / "images")
    anchors = Anchors(scene, seed=0, pool=21, options=opts)
    rows: dict[str, list] = {"ceiling": [], "floor": [], "a_ref": []}
    for i, cam in enumerate(sample_poses(caster, views, H, W, FOV, seed=7)):
        g = caster.render(cam)
        rows["ceiling"].append(anchors.ceiling(g, 100_000 + i))
        rows["floor"].append(anchors.floor(g, 100_000 + i))
        rows["a_ref"].append(to_uint8(reference_rendering(g)))
    real = [fit_image(load_rgb(p), H, W) for p in find_real(data / "real").images]
    reference, held = halves(real, 0)
    ladder = {"real_held_out": held[:views], "ceiling": rows["ceiling"], **defects(rows["ceiling"], 1),
              "a_ref": rows["a_ref"], "floor": rows["floor"]}
    return score(ladder, reference, seeds)


def footage(folder: Path, other: Path | None, seeds: int) -> dict:
    frames = [fit_image(load_rgb(p), H, W) for p in list_images(folder)]
    reference, held = halves(frames, 0)
    ladder = {"real_held_out": held, **defects(held, 1)}
    if other is not None:
        ladder["other_domain"] = [fit_image(load_rgb(p), H, W) for p in list_images(other)]
    return score(ladder, reference, seeds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="folder for the stand-in data (made once)")
    ap.add_argument("--views", type=int, default=64)
    ap.add_argument("--real-images", type=int, default=200)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--real-footage", type=Path, help="frames of a real video (the user's own footage)")
    ap.add_argument("--other-footage", type=Path, help="frames of another real domain")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    out = {"size": [H, W], "threads": args.threads, "seeds": args.seeds,
           "stand_in": stand_in(args.data, args.views, args.real_images, args.seeds)}
    if args.real_footage:
        out["real_footage"] = {"folder": args.real_footage.name, **footage(args.real_footage, args.other_footage,
                                                                           args.seeds)}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
