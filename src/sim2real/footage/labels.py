"""Label masks of the user's frames mapped onto the project's class table.

``--labels DIR`` holds one label image per frame, at the frame's path relative to its SRC folder
(``DIR/REL/NAME.png`` for ``SRC/REL/NAME.ext``; frames without one have no label). A label image
holds either a class id per pixel (single channel, or grey stored as RGB) or a colour per class
(RGB, as CholecSeg8k's colour masks). Neither says which class it means, so ``--label-map FILE``
does: a JSON object from the dataset's class ids (``"21"``) or colours (``"#ff7272"``) to class
names of the class table (:data:`sim2real.scene.classes.DEFAULT_CLASSES`: the paper's five,
stomach, duodenum, ..., instrument, vessel, bladder, diaphragm; ``--class-table FILE`` adds the
user's own) or null for ids and colours to ignore, e.g. for masks of class ids
``{"1": "liver", "2": "gallbladder", "7": "instrument", "0": null}`` and for CholecSeg8k's colour
masks (docs/footage.md has its full map)::

    {"#ff7272": "liver", "#ffa0a5": "gallbladder", "#aaff00": "instrument", "#a9ffb8": "instrument",
     "#7f7f7f": null}

Mapped pixels take the class's label id in the table (liver 0, ..., gallbladder 4, stomach 5, ...);
ids and colours not in the map, and pixels outside the content area, become 255 (background).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from sim2real.errors import UserError
from sim2real.fileio import read_json
from sim2real.scene.classes import LABEL_BACKGROUND, ClassTable

_COLOUR = re.compile(r"^#([0-9a-fA-F]{6})$")


@dataclass
class LabelMap:
    """A label map FILE read against a class table."""

    lut: np.ndarray
    """uint8 (65536,): dataset class id -> label id (255: background)."""
    colours: dict[int, int]
    """Packed colour 0xRRGGBB -> label id (255 for colours mapped to null)."""
    classes: ClassTable
    """The classes the map names (the table's entries, with their label ids)."""
    path: str

    def map_colours(self, rgb: np.ndarray, path: Path) -> np.ndarray:
        """An (H, W, 3) colour label image -> label ids; colours not in the map are background."""
        if not self.colours:
            raise UserError(f"label image {path} holds colours, but the label map {self.path} names class ids: "
                            "key it by colour ('#rrggbb') for colour masks")
        packed = (rgb[..., 0].astype(np.int64) << 16) | (rgb[..., 1].astype(np.int64) << 8) | rgb[..., 2]
        keys = np.fromiter(self.colours, np.int64)
        vals = np.fromiter(self.colours.values(), np.uint8)
        order = np.argsort(keys)
        keys, vals = keys[order], vals[order]
        pos = np.clip(np.searchsorted(keys, packed), 0, len(keys) - 1)
        return np.where(keys[pos] == packed, vals[pos], LABEL_BACKGROUND).astype(np.uint8)


def read_label_map(path: str | os.PathLike, table: ClassTable | None = None) -> LabelMap:
    """The label map FILE against ``table`` (default: the default classes); one error line when
    a key is neither a class id nor a colour, or a name is not in the table."""
    table = table if table is not None else ClassTable.defaults()
    raw = read_json(path, "label map")
    if not isinstance(raw, dict) or not raw:
        raise UserError(f"label map {path} must be a JSON object of class id or '#rrggbb' colour -> class name or null")
    lut = np.full(65536, LABEL_BACKGROUND, np.uint8)
    colours: dict[int, int] = {}
    names: list[str] = []
    for key, name in raw.items():
        if name is not None and (not isinstance(name, str) or name not in table):
            raise UserError(f"label map {path}: unknown class {name!r} for '{key}' "
                            f"(known: {', '.join(table)}, or null; --class-table FILE adds classes)")
        label = LABEL_BACKGROUND if name is None else table[name].label
        m = _COLOUR.match(key.strip())
        if m:
            colours[int(m.group(1), 16)] = label
        else:
            try:
                i = int(key)
            except ValueError:
                raise UserError(f"label map {path}: '{key}' is neither a class id (an integer 0..65535) "
                                "nor a colour ('#rrggbb')") from None
            if not 0 <= i < 65536:
                raise UserError(f"label map {path}: class id {i} is outside 0..65535")
            lut[i] = label
        if name is not None:
            names.append(name)
    return LabelMap(lut, colours, table.subset(names), str(path))


def label_path(labels: Path, frame: Path, root: Path) -> Path | None:
    """The label file of ``frame`` (found under its SRC folder ``root``) in ``labels``, if any."""
    rel = frame.relative_to(root)
    for ext in (".png", frame.suffix):
        p = (labels / rel).with_suffix(ext)
        if p.is_file():
            return p
    return None


def load_label(path: Path, size: tuple[int, int], label_map: LabelMap) -> np.ndarray:
    """The label image at ``path`` (class ids, or colours) mapped to label ids; its size must be the frame's."""
    try:
        with Image.open(path) as im:
            if im.mode in ("RGBA", "LA", "CMYK", "YCbCr") or (im.mode == "P" and label_map.colours):
                im = im.convert("RGB")  # a colour mask (a palette image keyed by colour: its colours; else its indices)
            a = np.asarray(im)
    except Exception as e:  # PIL raises many types for damaged files
        raise UserError(f"cannot read label image {path}: {e}") from None
    if a.shape[:2] != tuple(size):
        raise UserError(f"label image {path} is {a.shape[0]}x{a.shape[1]} but its frame is {size[0]}x{size[1]}")
    if a.ndim == 3 and a.shape[2] >= 3:
        if (a[..., 0] == a[..., 1]).all() and (a[..., 0] == a[..., 2]).all() and not label_map.colours:
            a = a[..., 0]  # a grey image of class ids stored as RGB
        else:
            return label_map.map_colours(a[..., :3], path)
    if a.ndim != 2:
        raise UserError(f"label image {path} must hold one class id per pixel or one colour per class")
    if a.dtype.kind not in "ui" or (a.size and (a.min() < 0 or a.max() > 65535)):
        raise UserError(f"label image {path} must hold integer class ids 0..65535")
    return label_map.lut[a.astype(np.int64)]
