"""Inputs for the translate/evaluate tests: a tiny trained run, labelled real images, fake FID
weights. Each is built once per pytest session under its base temp (like train_data.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from train_data import real_dir, scene_dir, tiny_config

SCENE_SEED = 11


def tiny_run(base: Path) -> Path:
    """A run of the tiny preset trained for 2 iterations on procedural scene 11 (CPU, seconds)."""
    from sim2real.engine.trainer import Trainer

    out = Path(base) / "eval_tiny_run"
    if (out / "checkpoints" / "last.pt").is_file():
        return out
    cfg = tiny_config(iterations=2, checkpoint_every=2, log_every=1, image_every=2, device="cpu")
    trainer = Trainer(cfg, [scene_dir(base, SCENE_SEED)], real_dir(base), out, progress=False)
    try:
        trainer.train()
    finally:
        trainer.close()
    return out


def labelled_real_dir(base: Path, n: int = 6) -> Path:
    """The stand-in real domain's layout: images/NAME.png and labels/NAME.png (0 = liver, 255 = background)."""
    from PIL import Image

    root = Path(base) / "labelled_real"
    if (root / "labels").is_dir():
        return root
    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    rng = np.random.default_rng(1)
    for k in range(n):
        h, w = 72, 150
        yy, xx = np.mgrid[0:h, 0:w]
        cy, cx, r = rng.uniform(20, 50), rng.uniform(40, 110), rng.uniform(12, 30)
        liver = (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
        img = np.empty((h, w, 3), np.float64)
        img[:] = (225, 185, 150)
        img[liver] = (125, 35, 35)
        img = np.clip(img + rng.normal(0, 8, img.shape), 0, 255).astype(np.uint8)
        Image.fromarray(img).save(root / "images" / f"frame_{k:02d}.png")
        Image.fromarray(np.where(liver, 0, 255).astype(np.uint8)).save(root / "labels" / f"frame_{k:02d}.png")
    return root


def fake_fid_weights(base: Path) -> Path:
    """FIDInceptionV3's random initial state dict saved as a weights file (not the real weights)."""
    import torch

    from sim2real.metrics.inception import FIDInceptionV3

    path = Path(base) / "fake_pt_inception.pth"
    if not path.is_file():
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            torch.save(FIDInceptionV3().state_dict(), path)
    return path
