"""What a trained run's own objective charges a perfect video (the detail study, docs/detail_study.md).

On views of the detail study's test path, score four videos with two terms of the generator's loss
of the run (the shipped model by default):

* ``ssim_ab``: the run's a -> b structure term, by default ``1 - MS-SSIM(grey a_ref, grey x)``, the
  paper's label-preserving term, with the run's window and scales (its weight is ``loss.ssim_ab``,
  5 in the paper); ``--set loss.ab_structure=edges`` scores the edge-recall variant instead
  (``sim2real/losses/structure.py``), to check a variant before training it;
* ``adv_b``: the LSGAN generator term ``sum_k mean((D_B,k(x) - 1)^2)`` under the run's trained
  real-domain discriminator D_B (weight ``loss.adv``, 1).

The videos: the run's translation (``model``), the ceiling (the stand-in real domain with one
appearance: what a perfect translation would look like), the floor (a new appearance every frame),
a_ref; and, for ``adv_b`` only, real training images. ``weighted`` is
``loss.adv * adv_b + loss.ssim_ab * ssim_ab``: if it is lower for ``model`` than for ``ceiling``,
the run's objective, with its discriminator as trained, prefers its own frames to a perfect video.
``shift4`` (the ceiling moved 4 px sideways) and ``other_view`` (the ceiling of another view of
the path) break the labels: a label-preserving term must charge them more than the ceiling.
Medians over the views; prints JSON.

Usage:
  python benchmarks/loss_probe.py --data D [--run RUN] [--views 20] [--set loss.ab_structure=edges]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    import torch

    from sim2real import shipped
    from sim2real.config import override
    from sim2real.data.real import load_rgb
    from sim2real.data.tensors import view_tensors
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.inference.anchors import Anchors, stand_in_options
    from sim2real.inference.realimages import fit_image
    from sim2real.inference.model import find_checkpoint, load_run
    from sim2real.losses import lsgan_gen_loss
    from sim2real.losses.structure import structure_ab_loss
    from sim2real.models.discriminator import MsImageDis
    from sim2real.presets import config_from_dict
    from sim2real.render.raycast import RayCaster
    from sim2real.render.reference import reference_rendering, to_uint8
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import Trajectory

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="the detail study's data folder (benchmarks/detail_study.py --data)")
    ap.add_argument("--run", default=None, help="a run folder (default: the shipped model)")
    ap.add_argument("--views", type=int, default=20, help="views of the test path, evenly spaced")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="change the run's loss settings")
    args = ap.parse_args()
    data = Path(args.data)
    info = json.loads((data / "done.json").read_text())
    if args.run:
        ckpt = find_checkpoint(args.run)
        model = load_run(args.run, device="cpu")
    else:
        ckpt = shipped.model_path()
        model = load_run(shipped.HERE, device="cpu", checkpoint=ckpt)
    state = load_checkpoint(ckpt)
    cfg = override(config_from_dict(state["config"]), args.set)
    dis_b = MsImageDis(3, cfg.discriminator)
    dis_b.load_state_dict({k[len("dis_b."):]: v.float() for k, v in state["dis"].items() if k.startswith("dis_b.")})
    dis_b.eval().requires_grad_(False)

    scene = Scene.load(info["scenes"][0])
    cams = Trajectory.load(data / "trajectory.txt").cameras
    cams = [cams[i] for i in np.linspace(0, len(cams) - 1, args.views).round().astype(int)]
    caster = RayCaster(scene)
    gbs = [caster.render(c) for c in cams]
    anchors = Anchors(scene, seed=0, pool=21, options=stand_in_options(info["real"])[0])
    H, W = model.train_size
    reals = sorted((Path(info["real"]) / "images").glob("*.png"))[: args.views]
    videos = {"model": model.translate_gbuffers(scene.name, gbs),
              "ceiling": [anchors.ceiling(g, i) for i, g in enumerate(gbs)],
              "floor": [anchors.floor(g, i) for i, g in enumerate(gbs)],
              "a_ref": [to_uint8(reference_rendering(g)) for g in gbs],
              "real": [fit_image(load_rgb(p), H, W) for p in reals]}
    videos["shift4"] = [np.roll(im, 4, axis=1) for im in videos["ceiling"]]
    videos["other_view"] = videos["ceiling"][3:] + videos["ceiling"][:3]

    def tensor(im: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.array(im)).permute(2, 0, 1)[None].float() / 127.5 - 1

    # a_ref as the structure term sees it in training (float, not the uint8 frame)
    a_ref = view_tensors(gbs, "i")["a_ref_i"].split(1)
    L = cfg.loss
    out = {}
    with torch.no_grad():
        for name, frames in videos.items():
            adv = [lsgan_gen_loss(dis_b(tensor(im))).item() for im in frames]
            row = {"adv_b": round(float(np.median(adv)), 4)}
            if name != "real":
                ssim = [structure_ab_loss(a, tensor(im), L).item() for a, im in zip(a_ref, frames)]
                row["ssim_ab"] = round(float(np.median(ssim)), 4)
                row["weighted"] = round(L.adv * row["adv_b"] + L.ssim_ab * row["ssim_ab"], 4)
            out[name] = row
    print(json.dumps({"run": str(args.run or "shipped"), "step": int(state.get("step", 0)), "views": len(cams),
                      "weights": {"adv": L.adv, "ssim_ab": L.ssim_ab}, "ab_structure": L.ab_structure,
                      "ssim_win": L.ssim_win, "rows": out}, indent=1))


if __name__ == "__main__":
    main()
