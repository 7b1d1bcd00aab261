"""The sample grids of an evaluation (``samples/`` beside report.md): random views with their
reference rows side by side, a few real images, and frames along each scene's trajectory."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from sim2real.fileio import atomic_write_image
from sim2real.grid import tile
from sim2real.inference.realimages import fit_image


def safe_name(name: str) -> str:
    return re.sub(r"[^0-9A-Za-z_.-]", "_", name)


def _sample_indices(T: int) -> list[int]:
    return sorted({0, T // 3, (2 * T) // 3, T - 1})


def _grid(rows: list[list[np.ndarray]], gap: int = 2) -> np.ndarray:
    """Tile uint8 RGB images (rows of columns) with white gaps, each fitted to the first one's size."""
    h, w = rows[0][0].shape[:2]
    return tile([[im if im.shape[:2] == (h, w) else fit_image(im, h, w) for im in row] for row in rows], gap)


def write_samples(out: Path, views: dict, real_imgs, seq_samples: dict, s) -> dict:
    """PNG sample grids under ``out/samples``; returns {title: relative path}."""
    samples: dict[str, str] = {}
    order = [r for r in ("a_ref", "model", "ceiling", "floor") if r in views]
    gen = views["model"]
    n = min(s.samples, len(gen))
    if n:
        rng = np.random.default_rng(s.seed)
        idx = sorted(rng.choice(len(gen), n, replace=False))
        atomic_write_image(out / "samples" / "views.png", _grid([[views[r][i] for r in order] for i in idx]))
        samples[f"Random views, one per row; columns: {', '.join(order)}"] = "samples/views.png"
    if real_imgs:
        atomic_write_image(out / "samples" / "real.png", _grid([real_imgs[: min(4, len(real_imgs))]]))
        samples["Real images (resized and centre-cropped as for FID)"] = "samples/real.png"
    for name, frames in seq_samples.items():
        idx = _sample_indices(len(frames["model"]))
        rel = f"samples/trajectory_{safe_name(name)}.png"
        atomic_write_image(out / rel, _grid([[frames[r][i] for i in idx] for r in order]))
        samples[f"Trajectory of '{name}', frames {', '.join(str(i) for i in idx)}; rows: {', '.join(order)}"] = rel
    return samples
