"""The "real held-out" reference row of the realism measures for a real set (JSON on stdout).

  python benchmarks/realset_reference.py REALSET [--size 128x256]

The evaluation compares translated views with every frame of a real set, fitted to the training
size (cover, centre crop). Without a ceiling on a real domain, the scale for its proxy distance
and detail ratio is what other real frames score: the held-out split's frames (other sources
than training's) against the train split's, and against all frames (the evaluation's reference
set, which then includes them: a lower bound).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from sim2real.data.cover import fit_image
from sim2real.fileio import read_json
from sim2real.inference.realimages import to_nchw
from sim2real.metrics.realism import proxy_colour_texture_distance


def row(gen: list[np.ndarray], real: list[np.ndarray]) -> dict:
    p = proxy_colour_texture_distance(to_nchw(gen), to_nchw(real))
    return {"proxy": p["proxy_colour_texture_distance"], "colour": p["proxy_colour_distance"],
            "texture": p["proxy_texture_distance"], "detail": p["proxy_grad_mean_gen"] / p["proxy_grad_mean_real"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("realset", type=Path)
    ap.add_argument("--size", default="128x256")
    args = ap.parse_args()
    h, w = (int(v) for v in args.size.split("x"))
    frames = read_json(args.realset / "manifest.json", "real set manifest")["frames"]
    imgs = {"train": [], "held_out": []}
    for f in frames:
        imgs[f["split"]].append(fit_image(np.asarray(Image.open(args.realset / f["file"]).convert("RGB")), h, w))
    out = {"realset": str(args.realset), "size": [h, w], "frames": {k: len(v) for k, v in imgs.items()},
           "held_out_vs_train": row(imgs["held_out"], imgs["train"]),
           "held_out_vs_all": row(imgs["held_out"], imgs["train"] + imgs["held_out"]),
           "train_vs_all": row(imgs["train"], imgs["train"] + imgs["held_out"])}
    json.dump(out, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
