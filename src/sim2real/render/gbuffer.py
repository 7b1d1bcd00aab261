"""The G-buffer of one view: what a ray caster returns and what every later stage reads.

Keys, shapes and units (also in docs/formats.md):

==================  ============  =========  ====================================================
key                 shape         dtype      meaning
==================  ============  =========  ====================================================
``K``               (3, 3)        float64    pinhole intrinsics (pixels)
``world_to_camera`` (4, 4)        float64    rigid transform, OpenCV axes (x right, y down, z fwd)
``depth``           (H, W)        float32    z-depth in the camera frame, mm; 0 = no surface
``distance``        (H, W)        float32    Euclidean camera-to-point distance, mm; 0 = none
``normal``          (H, W, 3)     float32    world-space unit normal, smooth, facing the camera
``object_id``       (H, W)        int16      index into ``classes``; -1 = background
``points``          (H, W, 3)     float32    world-space surface point, mm; 0 where no surface
``classes``         (O,)          str        class name of each object id
``class_table``     ()            str        JSON of the scene's class table (label ids, colours;
                                             :mod:`sim2real.scene.classes`); optional on load:
                                             older files get the default table
==================  ============  =========  ====================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from sim2real.errors import UserError
from sim2real.fileio import atomic_save_npz
from sim2real.scene.camera import Camera
from sim2real.scene.classes import LABEL_BACKGROUND, ClassTable

KEYS = ("K", "world_to_camera", "depth", "distance", "normal", "object_id", "points", "classes")


@dataclass
class GBuffer:
    K: np.ndarray
    world_to_camera: np.ndarray
    depth: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    object_id: np.ndarray
    points: np.ndarray
    classes: tuple[str, ...]
    class_table: ClassTable | None = None
    """Label id and colours of the classes; None: the defaults (unknown classes are refused)."""

    def __post_init__(self) -> None:
        table = self.class_table if self.class_table is not None else ClassTable.defaults()
        self.class_table = table.subset(self.classes)

    @property
    def height(self) -> int:
        return int(self.depth.shape[0])

    @property
    def width(self) -> int:
        return int(self.depth.shape[1])

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays: what :meth:`save` writes, less the headers and the class names."""
        return sum(np.asarray(getattr(self, k)).nbytes for k in KEYS if k != "classes")

    @property
    def mask(self) -> np.ndarray:
        """True where a ray hit a surface."""
        return self.object_id >= 0

    @property
    def camera(self) -> Camera:
        return Camera(self.K, self.world_to_camera, self.height, self.width)

    def class_index(self) -> np.ndarray:
        """Per-pixel label id of the class (the class table's ``label``; -1 = background).

        Object ids follow the scene's object order; this maps them to the classes' fixed ids
        (liver 0, fat 1, ligament 2, abdominal_wall 3, gallbladder 4, others from the table) so
        that a missing class never shifts an index."""
        lut = np.append(self.class_table.labels(self.classes), np.int16(-1))
        return lut[self.object_id]  # -1 indexes the appended background entry

    def labels(self) -> np.ndarray:
        """uint8 (H, W) label image: :meth:`class_index`, with
        :data:`sim2real.scene.classes.LABEL_BACKGROUND` (255) where there is no surface."""
        c = self.class_index()
        return np.where(c >= 0, c, LABEL_BACKGROUND).astype(np.uint8)

    def save(self, path: str | os.PathLike, durable: bool = True) -> None:
        """Uncompressed ``.npz`` of every key, arrays bit for bit as they are (docs/formats.md),
        written under a temporary name and renamed; ``durable=False`` skips the fsync (scratch
        files). :meth:`load` also reads the compressed files of earlier versions."""
        arrays = {k: getattr(self, k) for k in KEYS if k != "classes"}
        atomic_save_npz(path, {**arrays, "classes": np.array(self.classes, dtype=str),
                               "class_table": np.array(json.dumps(self.class_table.to_json()))}, durable=durable)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "GBuffer":
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in KEYS if k not in z]
                if missing:
                    raise UserError(f"view file {path} lacks key '{missing[0]}'")
                data = {k: z[k] for k in KEYS}
                table = str(z["class_table"]) if "class_table" in z else None
        except UserError:
            raise
        except Exception as e:  # zip / format errors of a damaged file
            raise UserError(f"cannot read view file {path}: {e}") from None
        data["classes"] = tuple(str(c) for c in data["classes"])
        if table is not None:
            try:
                data["class_table"] = ClassTable.from_json(json.loads(table), f"view file {path}")
            except ValueError as e:
                raise UserError(f"view file {path} has a damaged class table ({e})") from None
        return cls(**data)
