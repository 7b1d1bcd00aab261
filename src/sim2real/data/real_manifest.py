"""The layout and manifest of a real set (``REAL/manifest.json``), written by ``sim2real realset`` and read
by training and evaluation.

Layout of a real set::

    REAL/
      manifest.json                 this file's format (below)
      images/SOURCE/NNNNNN.jpg      frames, cropped to the content's box, short side <= height
      labels/SOURCE/NNNNNN.png      label id per pixel (the class table's ids, ``label_classes``;
                                    255 = background, unmapped or outside the content area)
      masks/SOURCE.png              content mask of the source's frames (255 = content)
      masks/SOURCE_NNNNNN.png       a frame's own mask, where its view differs from the source's

``manifest.json``::

    {"format": "sim2real-realset/1", "height": H, "classes": [...], "label_classes": {...} | null,
     "sources": [{"id", "path", "kind": "video"|"frames", "split": "train"|"held_out",
                  "frame_size": [h, w], "box": [top, left, bottom, right], "mask": "masks/ID.png",
                  "content_fraction", "overlay_fraction", "shape", "own_mask_frames", "kept",
                  "dropped": {reason: n}}],
     "frames": [{"file", "source", "index", "time", "size": [h, w], "mask", "phash", "split",
                 "label"}],
     "dropped": {reason: n}, "settings": {...}}

``index`` counts the source's sampled frames from 0 (frame folders: the file's position in name
order); ``time`` is the frame's time in seconds (videos; null for frame folders); ``phash`` the
64-bit perceptual hash (hex) of the content; ``mask`` the id of the frame's content mask, whose
file is ``masks/ID.png`` (the source's id, or the frame's own); ``label`` the label file or null.
``label_classes`` is the class table of the classes the label map names (class -> {"label",
"a_ref", "palette"}; :mod:`sim2real.scene.classes`), null without labels; ``classes`` their names
(without labels: the paper's five).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, read_json

FORMAT = "sim2real-realset/1"
MANIFEST = "manifest.json"
SPLITS = ("train", "held_out")
FRAME_KEYS = ("file", "source", "index", "time", "size", "mask", "phash", "split", "label")


def is_realset(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds a real set's manifest (any JSON file named manifest.json whose
    format is a real set's; the stand-in real domain's manifest is not one)."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        return False
    try:
        return read_json(path).get("format") == FORMAT
    except UserError:
        return False


def read_manifest(folder: str | os.PathLike) -> dict:
    """The checked manifest of the real set in ``folder`` (one error line when malformed)."""
    path = Path(folder) / MANIFEST
    m = read_json(path, "real set manifest")
    if m.get("format") != FORMAT:
        raise UserError(f"{path} is not a real set manifest (format {m.get('format')!r}, expected {FORMAT!r})")
    frames, sources = m.get("frames"), m.get("sources")
    if not isinstance(frames, list) or not isinstance(sources, list):
        raise UserError(f"real set manifest {path} lacks its 'frames' or 'sources' list")
    ids = {s.get("id") for s in sources if isinstance(s, dict)}
    for i, f in enumerate(frames):
        if not isinstance(f, dict) or any(k not in f for k in FRAME_KEYS):
            raise UserError(f"real set manifest {path}: frame {i} lacks one of {', '.join(FRAME_KEYS)}")
        if f["source"] not in ids or f["split"] not in SPLITS:
            raise UserError(f"real set manifest {path}: frame {i} names an unknown source or split")
    return m


def mask_file(mask_id: str) -> str:
    """The file of content mask ``mask_id``, relative to the real set."""
    return f"masks/{mask_id}.png"


def write_manifest(folder: str | os.PathLike, manifest: dict) -> None:
    atomic_write_json(Path(folder) / MANIFEST, manifest)


def load_mask(path: str | os.PathLike) -> np.ndarray:
    """A content mask PNG as boolean (True = content)."""
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("L")) > 127
    except Exception as e:  # PIL raises many types for damaged files
        raise UserError(f"cannot read content mask {path}: {e}") from None
