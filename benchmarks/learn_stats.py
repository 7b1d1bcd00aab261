"""Does a run learn? Translated frames vs real images, step 0 vs the latest checkpoint; prints JSON.

For a run folder (``sim2real train --out RUN``) it loads ``checkpoints/step_0000000.pt`` and
``checkpoints/last.pt``, translates the same held-out simulated views with each (view i of
``--samples`` samples drawn with a seed the run never used), draws as many random real crops,
and compares simple image statistics in [0, 1]:

* per-channel colour mean and standard deviation (over all pixels of all samples);
* mean gradient magnitude of the grey image (forward differences): a texture statistic.

``distance`` entries are |translated - real|, summed over the RGB channels for mean and std.
A learning run should move them towards 0 between step 0 and the latest checkpoint.

Texture detail: ``a_tex_gradient`` is the same gradient statistic on the projected neural
texture a_tex of the same views (its N features averaged, mapped to [0, 1]), taken inside
objects only (object outlines are left out). At step 0 every object's texture is one colour,
so it is 0 up to interpolation; detail learned on the textures raises it.
``--texture-png PATH`` writes the latest checkpoint's textures (``tanh`` of the texels, first 3
features as RGB) as one image per scene: a row per object, the 6 planes ``+x -x +y -y +z -z``
side by side, each object stretched to its own value range.

Usage: python benchmarks/learn_stats.py RUN [--samples 16] [--checkpoint PATH] [--texture-png PATH]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from torch.utils.data import default_collate

from sim2real.data.tensors import complete_on_device, widen

EVAL_SEED = 987654321


def gradient(grey: torch.Tensor, object_id: torch.Tensor | None = None) -> float:
    """Mean gradient magnitude (forward differences) of (K, H, W) images; with ``object_id``
    (K, H, W) only where a pixel and its right and lower neighbours show the same object."""
    gx = grey[:, :, 1:] - grey[:, :, :-1]
    gy = grey[:, 1:, :] - grey[:, :-1, :]
    mag = torch.sqrt(gx[:, :-1, :] ** 2 + gy[:, :, :-1] ** 2)
    if object_id is None:
        return float(mag.mean())
    o = object_id[:, :-1, :-1]
    inside = (o >= 0) & (o == object_id[:, :-1, 1:]) & (o == object_id[:, 1:, :-1])
    return float(mag[inside].mean())


def image_stats(images: torch.Tensor) -> dict:
    """images (K, 3, H, W) in [-1, 1] -> colour mean/std per channel and mean grey gradient magnitude."""
    x = (images.float().clamp(-1, 1) + 1) / 2
    grey = 0.299 * x[:, 0] + 0.587 * x[:, 1] + 0.114 * x[:, 2]
    return {"mean": x.mean((0, 2, 3)).tolist(), "std": x.transpose(0, 1).reshape(3, -1).std(1).tolist(),
            "gradient": gradient(grey)}


def distance(a: dict, b: dict) -> dict:
    return {"mean_l1": sum(abs(p - q) for p, q in zip(a["mean"], b["mean"])),
            "std_l1": sum(abs(p - q) for p, q in zip(a["std"], b["std"])),
            "gradient_abs": abs(a["gradient"] - b["gradient"])}


def translate(state: dict, batches: list[dict]) -> tuple[torch.Tensor, torch.Tensor]:
    """(b_hat, a_tex) of view i of every batch, with the generator of checkpoint ``state``."""
    from sim2real.data.datasets import resolve_scenes
    from sim2real.methods import get_method
    from sim2real.presets import config_from_dict

    cfg = config_from_dict(state["config"])
    method = get_method(cfg)
    sources = resolve_scenes(state["inputs"]["scenes"], cfg.data.height, cfg.data.width)
    gen, _ = method.build(sources)
    gen.load_state_dict(state["gen"])
    gen.eval()
    outs, texs = [], []
    with torch.no_grad():
        for b in batches:
            texs.append(method.a_tex(gen, b, "i"))
            outs.append(method.translate_frames(gen, b))
    return torch.cat(outs), torch.cat(texs)


def save_textures(state: dict, path: Path) -> list[Path]:
    """The checkpoint's textures as images (see the module docstring); returns the files written."""
    import numpy as np
    from PIL import Image

    written = []
    for key, value in state["gen"].items():
        if not (key.startswith("textures.") and key.endswith(".texture")):
            continue
        t = torch.tanh(value.float())[..., :3]  # (O, 6, S, S, <=3)
        lo = t.amin((1, 2, 3, 4), keepdim=True)
        hi = t.amax((1, 2, 3, 4), keepdim=True)
        t = ((t - lo) / (hi - lo).clamp_min(1e-6) * 255).round().byte()
        if t.shape[-1] < 3:
            t = t[..., :1].expand(*t.shape[:-1], 3)
        O, P, S = t.shape[:3]
        img = t.permute(0, 2, 1, 3, 4).reshape(O * S, P * S, 3).numpy()
        out = path.with_name(f"{path.stem}_{key.split('.')[1]}{path.suffix or '.png'}")
        Image.fromarray(np.ascontiguousarray(img)).save(out)
        written.append(out)
    return written


def main() -> None:
    from sim2real.data.datasets import TrainPairs, resolve_scenes
    from sim2real.data.real import RealImages
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.presets import config_from_dict

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--checkpoint", help="compare this checkpoint instead of last.pt")
    ap.add_argument("--texture-png", type=Path, help="write the latest textures as PATH_<scene>.png")
    args = ap.parse_args()
    ck = Path(args.run) / "checkpoints"
    first = load_checkpoint(ck / "step_0000000.pt")
    latest = load_checkpoint(Path(args.checkpoint) if args.checkpoint else ck / "last.pt")
    cfg = config_from_dict(latest["config"])
    sources = resolve_scenes(latest["inputs"]["scenes"], cfg.data.height, cfg.data.width)
    ds = TrainPairs(sources, RealImages(latest["inputs"]["real"], verify=False), cfg.data, seed=EVAL_SEED)
    batches = [complete_on_device(widen(default_collate([ds[s]]))) for s in range(args.samples)]
    real = image_stats(torch.cat([b["real"] for b in batches]))
    object_ids = torch.cat([b["object_id_i"] for b in batches])
    a_ref = image_stats(torch.cat([b["a_ref_i"] for b in batches]))
    result = {"run": str(args.run), "samples": args.samples, "real": real,
              "a_ref": {**a_ref, "distance_to_real": distance(a_ref, real)}}
    for name, state in (("step_0", first), ("latest", latest)):
        b_hat, a_tex = translate(state, batches)
        s = image_stats(b_hat)
        result[name] = {"step": state["step"], **s, "distance_to_real": distance(s, real),
                        "a_tex_gradient": gradient((a_tex.float().mean(1) + 1) / 2, object_ids)}
    if args.texture_png:
        result["texture_png"] = [str(p) for p in save_textures(latest, args.texture_png)]
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
