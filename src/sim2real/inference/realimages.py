"""Real images for the evaluation: the folder layout (a real set of `sim2real realset` has it too),
labels, and resizing to a metric's size (the one cover-resize, :mod:`sim2real.data.cover`).

**Content masks.** A real set's frames keep the corners of a circular view, black, and the bars
of an overlay (their content mask says where the view is). Every real frame the evaluation reads
(realism's reference and held-out halves, style sources, the segmenters' images and labels) is
therefore the largest window of the evaluation's aspect inside its frame's mask
(:meth:`sim2real.data.cover.ValidArea.inscribed_scale`, the window training crops from), resized
to the evaluation's size. Cropping was chosen over filling the outside with one colour on both
sides: a fill would have to be painted into the generated frames too, at the same place, and
every measure would then score a shared flat area instead of tissue; a crop compares tissue with
tissue at the price of the view's rim, which training never sees either.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from PIL import Image

from sim2real.data.cover import ValidArea, fit_image, resize_box
from sim2real.data.real import list_images, load_rgb
from sim2real.data.real_manifest import is_realset, load_mask, mask_file, read_manifest
from sim2real.errors import UserError


@dataclass
class RealSet:
    root: Path
    label_root: Path
    images: list[Path]
    labels: list[Path | None]
    """Label file of each image, or None."""
    masks: list[Path | None] = field(default_factory=list)
    """Content mask file of each image (a real set), or empty (a plain folder: images used whole)."""
    label_classes: dict | None = None
    """The class table of a real set's labels (its manifest's ``label_classes``), or None for
    labels without one (the stand-in's: the paper's five ids; the segmenters learn the liver alone)."""

    @property
    def labelled(self) -> list[tuple[Path, Path]]:
        return [(i, l) for i, l in zip(self.images, self.labels) if l is not None]

    def __post_init__(self):
        self._mask_index = dict(zip(self.images, self.masks))

    def mask_of(self, image: Path) -> Path | None:
        """The content mask file of ``image``, None without one."""
        return self._mask_index.get(image)

    def frames(self, images: Sequence[Path], height: int, width: int) -> list[np.ndarray]:
        """``images`` as uint8 (height, width, 3): the content window of each (module docstring),
        or, without a mask, the centre of the whole image."""
        windows = ContentWindows()
        return [windows.fit(load_rgb(p), self.mask_of(p), height, width) for p in images]


class ContentWindows:
    """The largest window of an aspect inside each content mask (mask files read once)."""

    def __init__(self):
        self._areas: dict[Path, ValidArea] = {}

    def box(self, mask: Path, shape: tuple[int, int], height: int, width: int) -> tuple[float, float, float, float]:
        """Source box (left, top, right, bottom) of the largest ``height:width`` window inside
        ``mask`` (and the bilinear filter's reach around it) of an image of ``shape``."""
        if mask not in self._areas:
            self._areas[mask] = ValidArea(load_mask(mask))
        area = self._areas[mask]
        if area.shape != tuple(shape):
            raise UserError(f"content mask {mask} is {area.shape[0]}x{area.shape[1]} but its image is "
                            f"{shape[0]}x{shape[1]}")
        # factor 1: the inscribed window itself; at that size its positions differ by a pixel or
        # two at most, and a fixed generator picks the same one in every run
        return area.draw(height, width, 1.0, np.random.default_rng(0))

    def fit(self, image: np.ndarray, mask: Path | None, height: int, width: int, nearest: bool = False) -> np.ndarray:
        """``image`` (or a label image, ``nearest``) at ``height x width``: its content window,
        or its centre without a mask."""
        if mask is None:
            return fit_image(image, height, width, nearest)
        return resize_box(image, self.box(mask, image.shape[:2], height, width), height, width, nearest)


def find_real(directory: str | os.PathLike) -> RealSet:
    """Real images and their labels.

    A real set (``sim2real realset``): its manifest's frames of both splits, with their labels,
    content masks and the labels' class table. ``DIR/images/`` + ``DIR/labels/`` (the stand-in
    real domain's layout): every image ``images/REL.ext`` may have ``labels/REL.png``. Otherwise
    every PNG/JPEG under ``DIR`` is an image (a ``DIR/labels/`` folder is skipped and read as above).
    """
    root = Path(directory)
    if not root.is_dir():
        raise UserError(f"real image folder {root} does not exist or is not a directory")
    if is_realset(root):
        return _realset(root)
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


def _realset(root: Path) -> RealSet:
    """A real set's frames (both splits), labels, content masks and label classes, from its manifest."""
    m = read_manifest(root)
    frames = m["frames"]
    if not frames:
        raise UserError(f"the real set {root} holds no frames")
    images = [root / f["file"] for f in frames]
    labels = [root / f["label"] if f["label"] else None for f in frames]
    masks = [root / mask_file(f["mask"]) for f in frames]
    return RealSet(root / "images", root / "labels", images, labels, masks, m.get("label_classes"))


def load_label(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as im:
            a = np.asarray(im)
    except Exception as e:
        raise UserError(f"cannot read label image {path}: {e}") from None
    if a.ndim != 2:
        raise UserError(f"label image {path} must be single-channel (uint8 class label id, 0 = liver, 255 = background)")
    return a


def load_segmentation_set(labelled: Sequence[tuple[Path, Path]], height: int, width: int,
                          masks: Sequence[Path | None] | None = None, label_ids: Sequence[int] = (0,)):
    """Labelled real images -> (images uint8 (N, 3, h, w), class masks bool (N, C, h, w): pixel ==
    ``label_ids[c]``; the default is the liver alone) at the segmenter's size (images bilinear,
    labels nearest; the content window of ``masks[i]`` where given, else cover + centre crop)."""
    xs, ys = [], []
    windows = ContentWindows()
    ids = np.asarray(label_ids, dtype=np.int64)
    for i, (ip, lp) in enumerate(labelled):
        img, lab = load_rgb(ip), load_label(lp)
        if lab.shape != img.shape[:2]:
            raise UserError(f"label {lp} is {lab.shape[0]}x{lab.shape[1]} but its image {ip} is "
                            f"{img.shape[0]}x{img.shape[1]}")
        mask = masks[i] if masks is not None else None
        xs.append(windows.fit(img, mask, height, width))
        lab = windows.fit(lab, mask, height, width, nearest=True)
        ys.append(lab[None] == ids[:, None, None])
    return to_nchw(xs), torch.from_numpy(np.stack(ys))


def real_halves(real_imgs: Sequence[np.ndarray], seed: int) -> tuple[list, list]:
    """The real images split in two halves by a seeded permutation: (reference, held out); the
    realism measures compare every row with the first and score the second as real frames."""
    perm = np.random.default_rng((seed, 2)).permutation(len(real_imgs))
    return [real_imgs[i] for i in perm[: len(perm) // 2]], [real_imgs[i] for i in perm[len(perm) // 2:]]


def to_nchw(frames: Sequence[np.ndarray]):
    return torch.from_numpy(np.stack(frames)).permute(0, 3, 1, 2).contiguous()




def shared_classes(real_set: RealSet, tables: Sequence) -> dict[str, int] | None:
    """The classes (name -> label id, the liver first) that a real set's labels and the scenes'
    class tables ``tables`` share: the segmenters learn these. None for a real folder without a
    class table of its labels (the stand-in's, or a plain folder: the liver alone, as always). A
    class whose label id differs between the labels and a scene is refused."""
    if real_set.label_classes is None or not real_set.labelled:
        return None
    out: dict[str, int] = {}
    for name, entry in sorted(real_set.label_classes.items(), key=lambda kv: (kv[0] != "liver", kv[1]["label"])):
        for table in tables:
            if name in table:
                if table[name].label != entry["label"]:
                    raise UserError(f"class '{name}' has label id {entry['label']} in the real set's labels but "
                                    f"{table[name].label} in a scene; give both the same class table")
                out[name] = int(entry["label"])
    return out
