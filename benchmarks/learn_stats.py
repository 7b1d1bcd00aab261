"""Does a run learn? Translated frames vs real images, step 0 vs the latest checkpoint; prints JSON.

For a run folder (``sim2real train --out RUN``) it loads ``checkpoints/step_0000000.pt`` and
``checkpoints/last.pt``, translates the same held-out simulated views with each (view i of
``--samples`` samples drawn with a seed the run never used), draws as many random real crops,
and compares simple image statistics in [0, 1]:

* per-channel colour mean and standard deviation (over all pixels of all samples);
* mean gradient magnitude of the grey image (forward differences): a texture statistic.

``distance`` entries are |translated - real|, summed over the RGB channels for mean and std.
A learning run should move them towards 0 between step 0 and the latest checkpoint.

Usage: python benchmarks/learn_stats.py RUN [--samples 16] [--checkpoint PATH]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from torch.utils.data import default_collate

EVAL_SEED = 987654321


def image_stats(images: torch.Tensor) -> dict:
    """images (K, 3, H, W) in [-1, 1] -> colour mean/std per channel and mean grey gradient magnitude."""
    x = (images.float().clamp(-1, 1) + 1) / 2
    grey = 0.299 * x[:, 0] + 0.587 * x[:, 1] + 0.114 * x[:, 2]
    gx = grey[:, :, 1:] - grey[:, :, :-1]
    gy = grey[:, 1:, :] - grey[:, :-1, :]
    grad = torch.sqrt(gx[:, :-1, :] ** 2 + gy[:, :, :-1] ** 2).mean()
    return {"mean": x.mean((0, 2, 3)).tolist(), "std": x.transpose(0, 1).reshape(3, -1).std(1).tolist(),
            "gradient": float(grad)}


def distance(a: dict, b: dict) -> dict:
    return {"mean_l1": sum(abs(p - q) for p, q in zip(a["mean"], b["mean"])),
            "std_l1": sum(abs(p - q) for p, q in zip(a["std"], b["std"])),
            "gradient_abs": abs(a["gradient"] - b["gradient"])}


def translate(state: dict, batches: list[dict]) -> torch.Tensor:
    from sim2real.config import TrainConfig, from_dict
    from sim2real.data.datasets import resolve_scenes
    from sim2real.engine.method import get_method

    cfg = from_dict(TrainConfig, state["config"])
    method = get_method(cfg)
    sources = resolve_scenes(state["inputs"]["scenes"], cfg.data.height, cfg.data.width)
    gen, _ = method.build(sources)
    gen.load_state_dict(state["gen"])
    gen.eval()
    outs = []
    with torch.no_grad():
        for b in batches:
            x_a = gen.translator.join_a(method.a_tex(gen, b, "i"), b["a_ref_i"])
            outs.append(gen.translator.a_to_b(x_a)[0])
    return torch.cat(outs)


def main() -> None:
    from sim2real.config import TrainConfig, from_dict
    from sim2real.data.datasets import TrainPairs, resolve_scenes
    from sim2real.data.real import RealImages
    from sim2real.engine.checkpoint import load_checkpoint

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--checkpoint", help="compare this checkpoint instead of last.pt")
    args = ap.parse_args()
    ck = Path(args.run) / "checkpoints"
    first = load_checkpoint(ck / "step_0000000.pt")
    latest = load_checkpoint(Path(args.checkpoint) if args.checkpoint else ck / "last.pt")
    cfg = from_dict(TrainConfig, latest["config"])
    sources = resolve_scenes(latest["inputs"]["scenes"], cfg.data.height, cfg.data.width)
    ds = TrainPairs(sources, RealImages(latest["inputs"]["real"], verify=False), cfg.data, seed=EVAL_SEED)
    batches = [default_collate([ds[s]]) for s in range(args.samples)]
    real = image_stats(torch.cat([b["real"] for b in batches]))
    a_ref = image_stats(torch.cat([b["a_ref_i"] for b in batches]))
    result = {"run": str(args.run), "samples": args.samples, "real": real,
              "a_ref": {**a_ref, "distance_to_real": distance(a_ref, real)}}
    for name, state in (("step_0", first), ("latest", latest)):
        s = image_stats(translate(state, batches))
        result[name] = {"step": state["step"], **s, "distance_to_real": distance(s, real)}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
