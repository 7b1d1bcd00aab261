"""Label masks of the user's frames mapped onto the project's classes.

``--labels DIR`` holds one single-channel class-id image per frame, at the frame's path relative
to its SRC folder (``DIR/REL/NAME.png`` for ``SRC/REL/NAME.ext``; frames without one have no
label). ``--label-map FILE`` is a JSON object from the dataset's class ids to the project's
class names (:data:`sim2real.scene.scene.CLASSES`) or null for ids to ignore, e.g. for
CholecSeg8k's class ids (its own documentation has the full list of 13)::

    {"21": "liver", "12": "fat", "25": "ligament", "11": "abdominal_wall", "5": "gallbladder", "50": null}

Ids not in the map, and pixels outside the content area, become 255 (background).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image

from sim2real.errors import UserError
from sim2real.fileio import read_json
from sim2real.scene.scene import CLASSES, LABEL_BACKGROUND


def read_label_map(path: str | os.PathLike) -> np.ndarray:
    """The label map FILE as a lookup table: uint8 (65536,) from a dataset id to a class index."""
    raw = read_json(path, "label map")
    lut = np.full(65536, LABEL_BACKGROUND, np.uint8)
    for key, name in raw.items():
        try:
            i = int(key)
        except ValueError:
            raise UserError(f"label map {path}: '{key}' is not a class id (an integer 0..65535)") from None
        if not 0 <= i < 65536:
            raise UserError(f"label map {path}: class id {i} is outside 0..65535")
        if name is None:
            continue
        if name not in CLASSES:
            raise UserError(f"label map {path}: unknown class '{name}' for id {i} "
                            f"(known: {', '.join(CLASSES)}, or null)")
        lut[i] = CLASSES.index(name)
    return lut


def label_path(labels: Path, frame: Path, root: Path) -> Path | None:
    """The label file of ``frame`` (found under its SRC folder ``root``) in ``labels``, if any."""
    rel = frame.relative_to(root)
    for ext in (".png", frame.suffix):
        p = (labels / rel).with_suffix(ext)
        if p.is_file():
            return p
    return None


def load_label(path: Path, size: tuple[int, int], lut: np.ndarray) -> np.ndarray:
    """The class-id image at ``path`` mapped through ``lut``; its size must be the frame's."""
    try:
        with Image.open(path) as im:
            a = np.asarray(im)
    except Exception as e:  # PIL raises many types for damaged files
        raise UserError(f"cannot read label image {path}: {e}") from None
    if a.ndim == 3 and a.shape[2] >= 3 and (a[..., 0] == a[..., 1]).all() and (a[..., 0] == a[..., 2]).all():
        a = a[..., 0]  # a grey image stored as RGB
    if a.ndim != 2:
        raise UserError(f"label image {path} must hold one class id per pixel (single channel)")
    if a.shape != tuple(size):
        raise UserError(f"label image {path} is {a.shape[0]}x{a.shape[1]} but its frame is {size[0]}x{size[1]}")
    if a.dtype.kind not in "ui" or (a.size and (a.min() < 0 or a.max() > 65535)):
        raise UserError(f"label image {path} must hold integer class ids 0..65535")
    return lut[a.astype(np.int64)]
