"""How much of the texture's band-limited start noise (``method.texture.init_noise=1``) survives N
steps of the CPU preset, with and without gradient through the reconstruction targets
(``method.target_grad``): the std of the texture's high-pass part (texel minus the mean of its four
neighbours) before and after, and their correlation. Prints one JSON line per setting.

Usage: python benchmarks/texture_noise_probe.py --data D --out RUNS --steps 120
(``--data`` as detail_study.py makes it)."""
import argparse
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
import detail_study

from sim2real.config import override
from sim2real.engine.trainer import Trainer
from sim2real.presets import budgeted


def hp(x):  # texel minus the mean of its 4 neighbours, per plane and feature
    x = x.permute(0, 1, 4, 2, 3).reshape(-1, 1, *x.shape[2:4])
    k = torch.tensor([[0, .25, 0], [.25, 0, .25], [0, .25, 0]]).view(1, 1, 3, 3)
    return x[..., 1:-1, 1:-1] - torch.nn.functional.conv2d(x, k)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True); ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=120)
    args = ap.parse_args()
    torch.set_num_threads(1)
    for flag in ("true", "false"):
        cfg = override(budgeted("cpu", "ours", "cpu"), [f"method.target_grad={flag}", "method.texture.init_noise=1.0",
                                                          f"iterations={args.steps}", "seed=0"])
        scenes, real, _ = detail_study.data(Path(args.data), cfg.data.height, cfg.data.width, 100)
        tr = Trainer(cfg, [str(s) for s in scenes], str(real / "images"), Path(args.out) / f"target_grad_{flag}", progress=False)
        tex = {k: t.texture.detach().clone() for k, t in tr.gen.textures.items()}
        t0 = time.time(); tr.train(); tr.close()
        out = {}
        for k, t in tr.gen.textures.items():
            a, b = tex[k], t.texture.detach()
            seen = (b - a).abs().amax(dim=(2, 3, 4)) > 1e-3  # planes that moved at all
            ha, hb = hp(a), hp(b)
            out[k] = {"hp_std_start": ha.std().item(), "hp_std_end": hb.std().item(),
                      "hp_corr": torch.corrcoef(torch.stack([ha.flatten(), hb.flatten()]))[0, 1].item(),
                      "planes_moved": int(seen.sum())}
        print(json.dumps({flag: {"steps": tr.step, "s": round(time.time() - t0), "textures": out}}), flush=True)


if __name__ == "__main__":
    main()
