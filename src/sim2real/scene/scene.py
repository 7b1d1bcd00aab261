"""Scenes: objects with a class and a triangle mesh in millimetres, saved as a directory.

Layout on disk::

    SCENE/
      scene.json        {"format": "sim2real-scene/1", "name", "objects": [{"name", "class",
                         "mesh", "normals"?}], "classes": {class: {"label", "a_ref", "palette"}},
                         "camera_region": {"center", "radii"}, "up", "anterior",
                         "source_units", "metadata"}
      meshes/NAME.ply   one binary PLY per object (any trimesh format is read on load)

The scene knows nothing about rendering. Object order defines the object ids of the
G-buffers; the scene's class table (:class:`sim2real.scene.classes.ClassTable`) gives each
class its label id and colours. Meshes are stored in millimetres whatever unit they were
imported in (``source_units``). An object with ``"normals": "mesh"`` carries its own vertex
normals in its PLY (smooth normals made at import); others get area-weighted vertex normals
from the ray caster. Scenes written before these fields existed load with the defaults
(the paper's class table, anterior +z, millimetres).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from sim2real.errors import UserError
from sim2real.fileio import read_json, staged_output_dir
from sim2real.scene.classes import (
    BACKGROUND_PALETTE,
    DEFAULT_CLASSES,
    LABEL_BACKGROUND,
    PAPER_CLASSES,
    ClassTable,
    check_name,
)
from sim2real.scene.conventions import ANTERIOR, UNITS
from sim2real.scene.io import check_mesh, has_vertex_normals, load_mesh

CLASSES: tuple[str, ...] = PAPER_CLASSES
"""The paper's five classes, label ids 0..4 (those of the procedural scenes). Other classes come
from a scene's class table (:mod:`sim2real.scene.classes`)."""

LABEL_PALETTE: dict[str, tuple[int, int, int]] = {
    **{c: DEFAULT_CLASSES[c].palette for c in PAPER_CLASSES}, "background": BACKGROUND_PALETTE}
"""Display colour of the paper's five labels (red, yellow, light blue, purple, green; black)."""


FORMAT = "sim2real-scene/1"
__all__ = ["CLASSES", "LABEL_BACKGROUND", "LABEL_PALETTE", "UNITS", "CameraRegion", "ClassTable", "Scene",
           "SceneObject"]


@dataclass
class SceneObject:
    name: str
    cls: str
    mesh: trimesh.Trimesh
    own_normals: bool = False
    """The mesh carries smooth vertex normals made at import (saved in its PLY)."""

    def __post_init__(self) -> None:
        check_name(self.cls)
        check_mesh(self.mesh, self.name)


@dataclass
class CameraRegion:
    """An axis-aligned ellipsoid (mm) inside which camera centres are sampled."""

    center: np.ndarray
    radii: np.ndarray

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        self.radii = np.asarray(self.radii, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(self.center)) and np.all(np.isfinite(self.radii)) and np.all(self.radii > 0)):
            raise UserError("camera region needs a finite centre and three positive radii (mm)")

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` points uniformly distributed in the ellipsoid."""
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
        return self.center + d * r * self.radii

    def clamp(self, points: np.ndarray) -> np.ndarray:
        """Pull points outside the ellipsoid back onto its surface."""
        q = (points - self.center) / self.radii
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        return self.center + q / np.maximum(n, 1.0) * self.radii

    def to_json(self) -> dict:
        return {"center": self.center.tolist(), "radii": self.radii.tolist()}


@dataclass
class Scene:
    name: str
    objects: list[SceneObject]
    camera_region: CameraRegion
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    """World direction towards the patient's head; it appears upwards in random views."""
    metadata: dict = field(default_factory=dict)
    class_table: ClassTable | None = None
    """Label id and colours of each class of the scene; None: the defaults (unknown classes are
    refused). Reduced to the scene's own classes."""
    anterior: np.ndarray = field(default_factory=lambda: np.array(ANTERIOR))
    """World direction towards the patient's front (the side cameras look at the liver from)."""
    source_units: str = "mm"
    """Unit of the files the meshes were imported from (they are stored in mm)."""

    def __post_init__(self) -> None:
        if not self.objects:
            raise UserError(f"scene '{self.name}' has no objects")
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise UserError(f"scene '{self.name}' has duplicate object names")
        self.up = _direction(self.up, "up")
        self.anterior = _direction(self.anterior, "anterior")
        if abs(float(self.up @ self.anterior)) > 0.99:
            raise UserError("scene 'up' (head) and 'anterior' directions must not be parallel")
        if self.source_units not in UNITS:
            raise UserError(f"scene units must be one of {', '.join(UNITS)}, got '{self.source_units}'")
        table = self.class_table if self.class_table is not None else ClassTable.defaults()
        self.class_table = table.subset(self.classes)

    @property
    def classes(self) -> tuple[str, ...]:
        return tuple(o.cls for o in self.objects)

    def objects_of(self, cls: str) -> list[int]:
        return [i for i, o in enumerate(self.objects) if o.cls == cls]

    def bounds(self) -> np.ndarray:
        """(O, 2, 3) per-object bounding boxes (min, max) in mm."""
        return np.stack([o.mesh.bounds for o in self.objects]).astype(np.float64)

    # --- persistence ---------------------------------------------------------------------------

    def to_json(self) -> dict:
        objects = []
        for o in self.objects:
            objects.append({"name": o.name, "class": o.cls, "mesh": f"meshes/{o.name}.ply"})
            if o.own_normals:
                objects[-1]["normals"] = "mesh"
        return {
            "format": FORMAT,
            "name": self.name,
            "objects": objects,
            "classes": self.class_table.to_json(),
            "camera_region": self.camera_region.to_json(),
            "up": self.up.tolist(),
            "anterior": self.anterior.tolist(),
            "source_units": self.source_units,
            "metadata": self.metadata,
        }

    def geometry_hash(self) -> str:
        """SHA-256 over every object's name, class, faces and vertices rounded to 0.01 mm: equal
        for the same geometry on any machine (the rounding absorbs most last-bit differences of
        the floating point), different when any vertex moves by more than that. The vertices are
        taken as a scene folder stores them (float32), so a scene hashes the same before
        :meth:`save` and after :meth:`load` (in float64, 51 of the 289,704 vertex coordinates of
        the demo's two scenes sit so close to a rounding boundary that float32 storage moves
        them across it)."""
        h = hashlib.sha256()
        for o in self.objects:
            h.update(f"{o.name}\0{o.cls}\0{len(o.mesh.vertices)}\0{len(o.mesh.faces)}\0".encode())
            stored = np.asarray(o.mesh.vertices, dtype=np.float32).astype(np.float64)
            h.update(np.ascontiguousarray(np.round(stored * 100.0).astype(np.int64)).tobytes())
            h.update(np.ascontiguousarray(np.asarray(o.mesh.faces, dtype=np.int64)).tobytes())
        return h.hexdigest()

    def save(self, directory: str | os.PathLike) -> Path:
        """Write the scene atomically: into a temporary sibling folder, then rename."""
        with staged_output_dir(directory) as tmp:
            (tmp / "meshes").mkdir()
            for o in self.objects:
                # vertex_normal None (trimesh's default): normals only if cached, as before
                o.mesh.export(tmp / "meshes" / f"{o.name}.ply", file_type="ply", encoding="binary",
                              vertex_normal=True if o.own_normals else None)
            (tmp / "scene.json").write_text(json.dumps(self.to_json(), indent=2) + "\n")
        return Path(directory)

    @classmethod
    def load(cls, directory: str | os.PathLike) -> "Scene":
        directory = Path(directory)
        spec_path = directory / "scene.json" if directory.is_dir() else directory
        if not spec_path.is_file():
            raise UserError(f"no scene at {directory} (expected a folder with scene.json)")
        spec = read_json(spec_path, "scene description")
        root = spec_path.parent
        try:
            objects = []
            for entry in spec["objects"]:
                own = entry.get("normals") == "mesh"
                mesh = load_mesh(root / entry["mesh"], entry["name"])
                if own and not has_vertex_normals(mesh):
                    raise UserError(f"mesh of object '{entry['name']}' in {root} lacks the vertex normals scene.json promises")
                objects.append(SceneObject(entry["name"], entry["class"], mesh, own))
            region = spec["camera_region"]
            table = (ClassTable.from_json(spec["classes"], f"{spec_path}") if "classes" in spec
                     else ClassTable.migrate(o.cls for o in objects))
            return cls(
                name=str(spec.get("name", root.name)),
                objects=objects,
                camera_region=CameraRegion(region["center"], region["radii"]),
                up=np.array(spec.get("up", [0.0, 1.0, 0.0])),
                metadata=dict(spec.get("metadata", {})),
                class_table=table,
                anterior=np.array(spec.get("anterior", ANTERIOR)),
                source_units=str(spec.get("source_units", "mm")),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise UserError(f"{spec_path} is not a valid scene description ({type(e).__name__}: {e})") from None


def _direction(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
        raise UserError(f"scene '{what}' must be a non-zero finite vector")
    return v / np.linalg.norm(v)
