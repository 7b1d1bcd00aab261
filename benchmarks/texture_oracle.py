"""How much consistent detail a neural texture's start noise holds before any translator touches it
(the detail study, docs/detail_study.md); prints JSON.

The "oracle" video of a texture start: the texture (flat class colours plus band-limited noise,
``method.texture.init_noise`` / ``init_noise_sigma``, or the line net of ``init_lines`` /
``init_lines_sigma``) projected into every
frame of the study's test path exactly as the translator's input a_tex is, and shown with a_ref's
shading::

    frame = (a_tex + 1) / 2 * a_ref / albedo(class)        (background black)

It is anchored to the surface by construction, so its ORB-1/5/10 counts are what a translator that
passed the texture through unchanged would score; they are set beside the ceiling's (the stand-in
real domain with one appearance) and a_ref's on the same path. ``grad`` is the frames' mean
absolute grey difference between neighbouring pixels (0-255 scale).

Usage (the study's data folder, made by benchmarks/detail_study.py):
  python benchmarks/texture_oracle.py --data D [--starts 1.5:1.0 3:1.0 6:1.0 3:0.5 4:1.0:lines] [--size 256]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _score(frames, points, masks, orb) -> dict:
    from sim2real.metrics.consistency import orb_curve

    curve = orb_curve(frames, points, masks, ks=(1, 5, 10), n_features=orb)
    return {f"orb_{k}_correct": v["mean_correct"] for k, v in curve.items()} | {
        f"orb_{k}_accuracy": v["accuracy"] for k, v in curve.items()}


def _grad(frames) -> float:
    import numpy as np

    g = [f.astype(np.float32).mean(-1) for f in frames]
    return float(np.mean([np.abs(np.diff(x, axis=0)).mean() + np.abs(np.diff(x, axis=1)).mean() for x in g]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="the detail study's data folder (scenes, trajectory.txt)")
    ap.add_argument("--starts", nargs="*", default=["1.5:1.0", "3:1.0", "6:1.0", "3:0.5"], metavar="SIGMA:AMPLITUDE[:SHAPE]",
                    help="noise blur (texels), amplitude (before the tanh) and shape (blobs or lines; default blobs) "
                         "of each texture start")
    ap.add_argument("--size", type=int, default=256, help="texture size (the CPU preset's: 256)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import numpy as np
    import torch

    from sim2real.config import TextureConfig
    from sim2real.inference.anchors import Anchors
    from sim2real.metrics.consistency import orb_settings_for
    from sim2real.render.raycast import RayCaster
    from sim2real.render.reference import class_albedo, reference_rendering, to_uint8
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import Trajectory
    from sim2real.texture.neural_texture import NOISE_SHAPES, NeuralTexture

    info = json.loads((Path(args.data) / "done.json").read_text())
    scene = Scene.load(info["scenes"][0])
    caster = RayCaster(scene)
    gbufs = [caster.render(c) for c in Trajectory.load(Path(args.data) / "trajectory.txt").cameras]
    points = [np.asarray(g.points, np.float32) for g in gbufs]
    masks = [g.mask for g in gbufs]
    orb = orb_settings_for(gbufs[0].width)
    albedo = class_albedo(scene.classes)
    a_ref = [reference_rendering(g) for g in gbufs]
    anchors = Anchors(scene)
    videos = {"ceiling": [anchors.ceiling(g, t) for t, g in enumerate(gbufs)], "a_ref": [to_uint8(a) for a in a_ref]}
    for start in args.starts:
        sigma, amp, shape = (start.split(":") + ["blobs"])[:3]
        sigma, amp = float(sigma), float(amp)
        torch.manual_seed(args.seed)
        if shape not in NOISE_SHAPES:
            sys.exit(f"texture_oracle: error: --starts {start}: the shape must be one of {', '.join(NOISE_SHAPES)}")
        kw = dict(init_noise=amp, init_noise_sigma=sigma) if shape == "blobs" else \
            dict(init_lines=amp, init_lines_sigma=sigma)
        tex = NeuralTexture(len(scene.classes), scene.bounds(), albedo, TextureConfig(size=args.size, features=3, **kw))
        frames = []
        with torch.no_grad():
            for g, a in zip(gbufs, a_ref):
                t = tex(torch.as_tensor(g.object_id)[None].long(), torch.as_tensor(g.points)[None].float(),
                        torch.as_tensor(g.normal)[None].float())[0].permute(1, 2, 0).numpy()
                shade = np.where(g.mask[..., None], a / np.clip(albedo[np.clip(g.object_id, 0, None)], 1e-3, None), 0.0)
                frames.append(to_uint8(np.clip((t + 1) / 2 * shade, 0, 1)))
        videos[f"noise {shape} sigma {sigma:g} amplitude {amp:g}"] = frames
        print(f"{start} done", file=sys.stderr)
    out = {"data": args.data, "frames": len(gbufs), "size": [gbufs[0].height, gbufs[0].width], "texture_size": args.size,
           "videos": {name: {**_score(f, points, masks, orb), "grad": _grad(f)} for name, f in videos.items()}}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
