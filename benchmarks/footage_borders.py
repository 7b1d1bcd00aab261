"""Do translated frames grow the real footage's black surround, corners or bars? (JSON on stdout)

  python benchmarks/footage_borders.py --scene SCENE --trajectory TRAJ \
      --translated shipped=DIR run=DIR [--real NAME=DIR[,DIR...] ...] [--figure PNG] [--json OUT]

For every translated sequence (``DIR/frames/*.png`` of ``sim2real translate``) and for the
untranslated reference rendering (a_ref) of the same trajectory, the share of near-black pixels
(grey < 20, the dark-surround threshold of ``sim2real.footage.content``) among the pixels where
the simulated view has tissue (a ray hit), in three regions of the frame:

* ``corners``: outside the ellipse inscribed in the frame (where a circular endoscope view that
  fills the frame's height leaves black);
* ``bottom_bar``: the bottom 6 % of the rows (where an on-screen-display bar sits);
* ``centre``: inside the ellipse of half the frame's size.

A model that learned "real means black corners" shows a ``corners`` share well above a_ref's and
above its own ``centre`` share. ``--real`` gives the same shares for real images (a real set, or
folders of frames) as the evaluation fits them to the frame size (cover, centre crop; all pixels,
there is no tissue mask), for scale: what the discriminator would see if crops were not kept
inside the content area.
``--figure`` writes a_ref and each translated sequence at frames 0, T/2 and T-1 (simulated views
only).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from sim2real.comparison.figures import _label
from sim2real.data.cover import fit_image
from sim2real.fileio import atomic_write_image, atomic_write_json
from sim2real.grid import tile
from sim2real.inference.frames import iter_gbuffers
from sim2real.inference.realimages import find_real
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.trajectory import Trajectory

DARK = 20
"""Grey level below which a pixel counts as near-black (the dark surround's mean threshold)."""
BAR = 0.06
"""Share of the rows at the bottom taken as the on-screen-display band."""


def regions(h: int, w: int) -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:h, 0:w]
    r = ((y + 0.5 - h / 2) / (h / 2)) ** 2 + ((x + 0.5 - w / 2) / (w / 2)) ** 2
    return {"corners": r > 1.0, "bottom_bar": y >= h - max(1, round(BAR * h)), "centre": r <= 0.25}


def grey(img: np.ndarray) -> np.ndarray:
    return img[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)


def dark_shares(frames: list[np.ndarray], tissue: list[np.ndarray] | None) -> dict[str, float | None]:
    h, w = frames[0].shape[:2]
    out = {}
    for name, reg in regions(h, w).items():
        dark = n = 0
        for k, f in enumerate(frames):
            sel = reg & tissue[k] if tissue is not None else reg
            dark += int((grey(f)[sel] < DARK).sum())
            n += int(sel.sum())
        out[name] = dark / n if n else None
    return out


def load_frames(folder: Path) -> list[np.ndarray]:
    files = sorted((folder / "frames").glob("*.png"))
    if not files:
        raise SystemExit(f"no frames in {folder / 'frames'}")
    return [np.asarray(Image.open(f).convert("RGB")) for f in files]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, required=True)
    ap.add_argument("--trajectory", type=Path, required=True)
    ap.add_argument("--translated", nargs="+", required=True, metavar="NAME=DIR")
    ap.add_argument("--real", nargs="*", default=[], metavar="NAME=DIR")
    ap.add_argument("--figure", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    cams = Trajectory.load(args.trajectory).cameras
    gbuffers = list(iter_gbuffers(args.scene, cams, 1, 8))
    tissue = [g.mask for g in gbuffers]
    seqs = {"a_ref": [to_uint8(reference_rendering(g)) for g in gbuffers]}
    for item in args.translated:
        name, folder = item.split("=", 1)
        seqs[name] = load_frames(Path(folder))
        if len(seqs[name]) != len(cams):
            raise SystemExit(f"{folder}: {len(seqs[name])} frames, the trajectory has {len(cams)}")
    h, w = seqs["a_ref"][0].shape[:2]
    result = {"dark_below": DARK, "frames": len(cams), "size": [h, w],
              "region_share_of_frame": {k: float(v.mean()) for k, v in regions(h, w).items()},
              "tissue_share": {k: float(np.mean([t[v].mean() for t in tissue])) for k, v in regions(h, w).items()},
              "translated": {name: dark_shares(f, tissue) for name, f in seqs.items()}, "real": {}}
    for item in args.real:
        name, folders = item.split("=", 1)
        dirs = [Path(f) for f in folders.split(",") if Path(f).is_dir()]  # video files are skipped
        imgs = [fit_image(np.asarray(Image.open(p).convert("RGB")), h, w) for d in dirs for p in find_real(d).images]
        if imgs:
            result["real"][name] = {"images": len(imgs), **dark_shares(imgs, None)}
    if args.figure:
        T = len(cams)
        cols = [0, T // 2, T - 1]
        atomic_write_image(args.figure, tile([[_label(name, h, w), *(f[c] for c in cols)] for name, f in seqs.items()]))
        result["figure"] = {"file": str(args.figure), "columns": cols}
    if args.json:
        atomic_write_json(args.json, result)
    json.dump(result, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
