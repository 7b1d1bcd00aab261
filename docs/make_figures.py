"""Remake the figures of README.md and docs/ that come from the demo and the stand-in real domain.

    python docs/make_figures.py [--demo DEMO] [--out docs] [--device auto|cpu|cuda]

``--demo`` is the output folder of ``sim2real demo --out DEMO``; without it the demo runs first
(into a temporary folder, about 3 to 5 minutes on a 2-core CPU). Writes into ``--out``:

* ``demo_overview.png`` (the README's picture): view 0 of the demo's test trajectory as simulated
  (the reference rendering a_ref), translated by the shipped model, translated again after the
  camera went to the last view and back (the revisit), its ground-truth depth (turbo colour map,
  near = blue; black = no surface) and its ground-truth optical flow to frame 1 (hue = direction,
  brightness = speed, scaled to the frame's largest flow), from ``DEMO/video/ground_truth/``;
* ``demo_side_by_side.png``: a copy of ``DEMO/side_by_side.png``;
* ``shipped_views.png``: a copy of the evaluation's sample views ``DEMO/evaluation/samples/views.png``;
* ``shipped_texture.png``: the shipped model's texture of the first scene (first three features
  as RGB, ``tanh`` of the texels, one row per object, the six planes side by side, halved), drawn by
  ``save_textures`` of ``benchmarks/learn_stats.py``;
* ``realdomain_montage.png``: the first eight views of ``sim2real realdomain --scenes S1000 S1001
  S1002 --images 8 --seed 0`` (scenes ``sim2real scene generate --seed 1000..1002``), rendered
  at 256x512 and shown at 128x256 (Lanczos), two per row.

Prints a JSON line with what was written and where it came from.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image

from sim2real.engine.checkpoint import load_checkpoint
from sim2real.fileio import atomic_path, atomic_write_image
from sim2real.grid import tile
from sim2real.inference.gt_formats import read_depth_png, read_flo
from sim2real.inference.frames import iter_gbuffers
from sim2real.inference.model import load_run
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args) -> None:
    """Run ``sim2real ARGS`` with the interpreter of this script (its venv), failing loudly."""
    subprocess.run([str(Path(sys.executable).with_name("sim2real")), *map(str, args)], check=True)


def depth_image(depth_mm: np.ndarray) -> np.ndarray:
    """Depth as RGB: turbo colour map from the nearest to the farthest surface, black = no surface."""
    valid = depth_mm > 0
    lo, hi = depth_mm[valid].min(), depth_mm[valid].max()
    scaled = np.zeros(depth_mm.shape, np.uint8)
    scaled[valid] = np.round((depth_mm[valid] - lo) / max(hi - lo, 1e-6) * 255).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[~valid] = 0
    return rgb


def flow_image(flow: np.ndarray) -> np.ndarray:
    """Optical flow as RGB: hue = direction, value = speed relative to the largest in the frame."""
    mag, ang = cv2.cartToPolar(flow[..., 0].astype(np.float32), flow[..., 1].astype(np.float32))
    hsv = np.zeros((*flow.shape[:2], 3), np.uint8)
    hsv[..., 0] = np.round(ang * 90 / np.pi).astype(np.uint8)  # OpenCV's hue runs 0..179
    hsv[..., 1] = 255
    hsv[..., 2] = np.round(mag / max(float(mag.max()), 1e-6) * 255).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def overview(demo: Path, png: Path, device: str) -> dict:
    """The README's picture: a_ref, translated, revisited, depth and flow of view 0."""
    scene_dir = demo / "scenes" / "sim_0"  # the scene the demo translated and evaluated
    cams = Trajectory.load(demo / "trajectory.txt").cameras
    gbuffers = list(iter_gbuffers(scene_dir, cams, None, 8))
    model = load_run(demo / "run", device=device)
    seq = model.sequence(Scene.load(scene_dir).name)
    forward = seq.translate(gbuffers)
    # view 0 again after the camera went to the last view and back, continuing the same sequence
    revisit = seq.translate(gbuffers[::-1])[-1]
    gt = demo / "video" / "ground_truth"
    depth = read_depth_png(gt / "depth" / "000000.png")
    flow = read_flo(gt / "flow" / "000000.flo")
    atomic_write_image(png, tile([[to_uint8(reference_rendering(gbuffers[0])), forward[0], revisit,
                                   depth_image(depth), flow_image(flow)]]))
    diff = float(np.abs(forward[0].astype(np.int16) - revisit.astype(np.int16)).mean())
    return {"file": str(png), "frames": len(cams), "revisit_mean_abs_difference": diff,
            "flow_max_px": float(np.linalg.norm(flow, axis=-1).max())}


def texture(demo: Path, png: Path) -> dict:
    """The shipped model's texture of the first scene, through learn_stats' own drawing."""
    spec = importlib.util.spec_from_file_location("learn_stats", ROOT / "benchmarks" / "learn_stats.py")
    learn_stats = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(learn_stats)
    state = load_checkpoint(demo / "run" / "checkpoints" / "last.pt")
    with tempfile.TemporaryDirectory() as tmp:
        first = learn_stats.save_textures(state, Path(tmp) / "texture.png")[0]
        img = Image.open(first).convert("RGB")
        img = img.resize((img.width // 2, img.height // 2), Image.LANCZOS)
        atomic_write_image(png, np.asarray(img))
    return {"file": str(png), "scene": first.stem.split("_", 1)[1]}


def montage(png: Path) -> dict:
    """Eight stand-in frames: realdomain at 256x512, shown at 128x256, two per row."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scenes = []
        for seed in (1000, 1001, 1002):
            _cli("scene", "generate", "--seed", seed, "--out", tmp / f"S{seed}")
            scenes.append(tmp / f"S{seed}")
        _cli("realdomain", "--scenes", *scenes, "--images", 8, "--seed", 0, "--out", tmp / "real", "--quiet")
        frames = [np.asarray(Image.open(p).convert("RGB").resize((256, 128), Image.LANCZOS))
                  for p in sorted((tmp / "real" / "images").glob("*.png"))[:8]]
    atomic_write_image(png, tile([frames[i:i + 2] for i in range(0, 8, 2)], gap=0))
    return {"file": str(png), "frames": len(frames)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--demo", type=Path, help="a folder written by 'sim2real demo --out DEMO' (default: run the demo)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs", help="where the figures go (default docs/)")
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    args = ap.parse_args()
    device = args.device if args.device != "auto" else ("cuda" if torch.cuda.is_available() else "cpu")
    with tempfile.TemporaryDirectory() as tmp:
        demo = args.demo
        if demo is None:
            demo = Path(tmp) / "demo"
            _cli("demo", "--out", demo, "--device", device)
        if not (demo / "demo.json").is_file():
            sys.exit(f"error: {demo} is not a finished demo folder (no demo.json)")
        args.out.mkdir(parents=True, exist_ok=True)
        made = {"demo": json.loads((demo / "demo.json").read_text()).get("model"),
                "overview": overview(demo, args.out / "demo_overview.png", device)}
        for src, name in ((demo / "side_by_side.png", "demo_side_by_side.png"),
                          (demo / "evaluation" / "samples" / "views.png", "shipped_views.png")):
            with atomic_path(args.out / name) as tmp_png:
                shutil.copyfile(src, tmp_png)
            made[name] = str(args.out / name)
        made["texture"] = texture(demo, args.out / "shipped_texture.png")
    made["montage"] = montage(args.out / "realdomain_montage.png")
    print(json.dumps(made))


if __name__ == "__main__":
    main()
