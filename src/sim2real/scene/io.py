"""Mesh import through trimesh (OBJ, PLY, STL, glTF/GLB, OFF, ...), with clear errors.

Multi-object files (GLB scenes, OBJ with several ``o`` groups) are split into their parts,
named after the glTF node or OBJ object names.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from sim2real.errors import UserError
from sim2real.scene.scene import CLASSES, check_mesh


def _read(path: Path) -> trimesh.Trimesh | trimesh.Scene:
    if not path.is_file():
        raise UserError(f"mesh file {path} does not exist")
    kwargs = {"split_objects": True, "group_material": False} if path.suffix.lower() == ".obj" else {}
    try:
        return trimesh.load(str(path), process=False, **kwargs)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise UserError(f"cannot read mesh file {path}: {type(e).__name__}: {e}") from None


def _as_trimesh(geom, label: str) -> trimesh.Trimesh:
    if not isinstance(geom, trimesh.Trimesh):
        raise UserError(f"mesh '{label}' is not a triangle mesh (found {type(geom).__name__})")
    return geom


def load_parts(path: str | os.PathLike) -> dict[str, trimesh.Trimesh]:
    """All triangle meshes of a file, keyed by part name, in world coordinates."""
    path = Path(path)
    loaded = _read(path)
    if isinstance(loaded, trimesh.Scene):
        if not loaded.geometry:
            raise UserError(f"mesh file {path} holds no geometry")
        parts = {}
        for node in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node]
            geom = _as_trimesh(loaded.geometry[geom_name], f"{path.name}:{node}").copy()
            geom.apply_transform(transform)
            parts[str(node)] = geom
        return parts
    return {path.stem: _as_trimesh(loaded, str(path))}


def load_mesh(path: str | os.PathLike, name: str) -> trimesh.Trimesh:
    """One mesh from a file; several parts are concatenated into one object."""
    parts = load_parts(path)
    mesh = next(iter(parts.values())) if len(parts) == 1 else trimesh.util.concatenate(list(parts.values()))
    check_mesh(mesh, name)
    return mesh


def class_from_name(name: str, mapping: dict[str, str]) -> str:
    """Class of a part: an explicit ``mapping`` entry, else a class name the part name starts with."""
    if name in mapping:
        return mapping[name]
    low = name.lower().replace(" ", "_").replace("-", "_")
    for cls in sorted(CLASSES, key=len, reverse=True):
        if low.startswith(cls):
            return cls
    raise UserError(
        f"cannot tell the class of mesh part '{name}'; name it with --class '{name}=CLASS' "
        f"(classes: {', '.join(CLASSES)})"
    )


def parse_vector(text: str, n: int, what: str) -> np.ndarray:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != n or not np.all(np.isfinite(values)):
        raise UserError(f"{what} must be {n} comma-separated finite numbers, got '{text}'")
    return np.array(values)
