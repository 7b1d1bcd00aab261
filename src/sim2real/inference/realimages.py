"""Real images for the evaluation: the folder layout (a real set of `sim2real realset` has it too),
labels, and resizing to a metric's size (the one cover-resize, :mod:`sim2real.data.cover`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from PIL import Image

from sim2real.data.cover import fit_image
from sim2real.data.real import list_images, load_rgb
from sim2real.errors import UserError


@dataclass
class RealSet:
    root: Path
    label_root: Path
    images: list[Path]
    labels: list[Path | None]
    """Label file of each image, or None."""

    @property
    def labelled(self) -> list[tuple[Path, Path]]:
        return [(i, l) for i, l in zip(self.images, self.labels) if l is not None]


def find_real(directory: str | os.PathLike) -> RealSet:
    """Real images and their labels.

    ``DIR/images/`` + ``DIR/labels/`` (the stand-in real domain's layout): every image
    ``images/REL.ext`` may have ``labels/REL.png``. Otherwise every PNG/JPEG under ``DIR`` is an
    image (a ``DIR/labels/`` folder is skipped and read as above).
    """
    root = Path(directory)
    if not root.is_dir():
        raise UserError(f"real image folder {root} does not exist or is not a directory")
    img_root = root / "images" if (root / "images").is_dir() else root
    lab_root = root / "labels"
    images = [p for p in list_images(img_root) if lab_root not in p.parents]
    if not images:
        raise UserError(f"no real images (png/jpg) found under {img_root}")
    labels = []
    for p in images:
        lp = (lab_root / p.relative_to(img_root)).with_suffix(".png")
        labels.append(lp if lab_root.is_dir() and lp.is_file() else None)
    return RealSet(img_root, lab_root, images, labels)


def load_label(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as im:
            a = np.asarray(im)
    except Exception as e:
        raise UserError(f"cannot read label image {path}: {e}") from None
    if a.ndim != 2:
        raise UserError(f"label image {path} must be single-channel (uint8 class index, 0 = liver, 255 = background)")
    return a


def load_segmentation_set(labelled: Sequence[tuple[Path, Path]], height: int, width: int):
    """Labelled real images -> (images uint8 (N, 3, h, w), liver masks bool (N, h, w)) at the
    segmenter's size (images bilinear, labels nearest; cover + centre crop)."""
    xs, ys = [], []
    for ip, lp in labelled:
        img, lab = load_rgb(ip), load_label(lp)
        if lab.shape != img.shape[:2]:
            raise UserError(f"label {lp} is {lab.shape[0]}x{lab.shape[1]} but its image {ip} is "
                            f"{img.shape[0]}x{img.shape[1]}")
        xs.append(fit_image(img, height, width))
        ys.append(fit_image(lab, height, width, nearest=True) == 0)
    return to_nchw(xs), torch.from_numpy(np.stack(ys))


def to_nchw(frames: Sequence[np.ndarray]):
    return torch.from_numpy(np.stack(frames)).permute(0, 3, 1, 2).contiguous()


