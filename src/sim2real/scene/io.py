"""Mesh import through trimesh (OBJ, PLY, STL, glTF/GLB, OFF, ...), with clear errors.

Multi-object files (GLB scenes, OBJ with several ``o`` groups) are split into their parts,
named after the glTF node or OBJ object names. :func:`check_units` refuses sizes implausible
for the unit the user gave; :func:`smooth_normals` gives meshes without vertex normals (STL
always, OBJ often) smooth, angle-weighted ones.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from sim2real.errors import UserError, reason
from sim2real.scene.blend import blend_to_glb
from sim2real.scene.classes import ClassTable
from sim2real.scene.conventions import DEFAULT_CREASE_DEG, UNITS

LIVER_ACROSS_MM = (20.0, 500.0)
"""Plausible size of a liver (largest side of its bounding box), mm."""
SCENE_ACROSS_MM = (20.0, 2000.0)
"""Plausible size of a scene without a liver (largest side of its bounding box), mm."""
NORMALS_SUFFIXES = (".stl", ".obj")
"""File types whose meshes get smooth normals at import when they carry none."""
FOLDER_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off", ".blend")
"""File types a folder given as a mesh contributes (any other file in it is left out)."""


def check_mesh(mesh: trimesh.Trimesh, name: str) -> None:
    """Refuse meshes the ray caster cannot use: empty, non-triangle, non-finite."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise UserError(f"mesh '{name}' is not a triangle mesh")
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise UserError(f"mesh '{name}' is empty (no triangles)")
    if mesh.faces.ndim != 2 or mesh.faces.shape[1] != 3:
        raise UserError(f"mesh '{name}' is not made of triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise UserError(f"mesh '{name}' has NaN or infinite vertices")


def mesh_files(spec: str) -> list[str]:
    """``PATH[=CLASS]`` as one or more specs: a folder becomes its mesh files (by
    :data:`FOLDER_SUFFIXES`, sorted, not recursive), each with the folder's ``=CLASS`` if given."""
    path, eq, cls = spec.partition("=")
    if not Path(path).is_dir():
        return [spec]
    files = sorted(p for p in Path(path).iterdir() if p.is_file() and p.suffix.lower() in FOLDER_SUFFIXES)
    if not files:
        raise UserError(f"folder {path} holds no mesh files ({', '.join(s[1:] for s in FOLDER_SUFFIXES)})")
    return [f"{f}{eq}{cls}" for f in files]


def _missing(path: Path) -> UserError:
    """The error for a mesh file that is not there; a pattern the shell left unexpanded says so."""
    if any(c in str(path) for c in "*?["):
        return UserError(f"no mesh file matches {path}")
    return UserError(f"mesh file {path} does not exist")


def _read(path: Path) -> trimesh.Trimesh | trimesh.Scene:
    if not path.is_file():
        raise _missing(path)
    kwargs = {"split_objects": True, "group_material": False} if path.suffix.lower() == ".obj" else {}
    try:
        return trimesh.load(str(path), process=False, **kwargs)
    except IndexError:  # trimesh indexes the vertices with the faces as read
        raise UserError(f"cannot read mesh file {path}: a face refers to a vertex the file does not have") from None
    except Exception as e:  # trimesh raises many types for unreadable files
        raise UserError(f"cannot read mesh file {path}: {type(e).__name__}: {reason(e)}") from None


def _as_trimesh(geom, label: str) -> trimesh.Trimesh:
    if not isinstance(geom, trimesh.Trimesh):
        raise UserError(f"mesh '{label}' is not a triangle mesh (found {type(geom).__name__})")
    faces = np.asarray(geom.faces)
    # trimesh keeps faces past the vertices when it loads without processing (PLY, OFF); bounds
    # and normals would then fail with an IndexError
    lo, hi = (int(faces.min()), int(faces.max())) if faces.size else (0, 0)
    if faces.size and (lo < 0 or hi >= len(geom.vertices)):
        bad = hi if hi >= len(geom.vertices) else lo
        raise UserError(f"mesh '{label}': a face refers to vertex {bad}, but the mesh has {len(geom.vertices)} vertices")
    return geom


def load_parts(path: str | os.PathLike) -> dict[str, trimesh.Trimesh]:
    """All triangle meshes of a file, keyed by part name, in world coordinates. A ``.blend``
    file is exported to GLB by Blender's module first (:mod:`sim2real.scene.blend`)."""
    path = Path(path)
    if path.suffix.lower() == ".blend":
        if not path.is_file():
            raise _missing(path)
        with tempfile.TemporaryDirectory(prefix="sim2real-blend-") as tmp:
            glb = Path(tmp) / f"{path.stem}.glb"
            blend_to_glb(path, glb)
            return load_parts(glb)
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


def class_from_name(name: str, mapping: dict[str, str], table: ClassTable | None = None) -> str:
    """Class of a part: an explicit ``mapping`` entry, else a class of ``table`` (default: the
    default classes) that the part name starts with (case, spaces and '-' ignored: 'Kidney_left'
    is a kidney, 'Small bowel 2' and 'SmallBowel' a small_bowel)."""
    if name in mapping:
        return mapping[name]
    known = list(table if table is not None else ClassTable.defaults())
    low = name.lower().replace(" ", "_").replace("-", "_").replace(".", "_")
    for cls in sorted(known, key=len, reverse=True):
        if low.startswith(cls) or low.replace("_", "").startswith(cls.replace("_", "")):  # 'AbdominalWall'
            return cls
    raise UserError(
        f"cannot tell the class of mesh part '{name}'; name it with --class '{name}=CLASS' "
        f"(classes: {', '.join(known)})"
    )


def has_vertex_normals(mesh: trimesh.Trimesh) -> bool:
    """Whether the file gave the mesh its own vertex normals (trimesh keeps loaded ones cached)."""
    return "vertex_normals" in mesh._cache and len(mesh._cache["vertex_normals"]) == len(mesh.vertices)


def smooth_normals(mesh: trimesh.Trimesh, crease_deg: float = DEFAULT_CREASE_DEG) -> trimesh.Trimesh:
    """A copy of ``mesh`` with smooth vertex normals: vertices at the same position are welded
    (STL stores every triangle with its own three), the surface is cut along edges whose faces
    meet at more than ``crease_deg`` (:func:`trimesh.graph.smooth_shade`: the connected patches of
    smooth edges get their own vertices), and each vertex normal is the angle-weighted mean of
    its faces' normals (:func:`trimesh.geometry.weighted_vertex_normals`, trimesh's default).
    A crease that ends inside a smooth patch does not cut it (smooth_shade cuts patches, not
    edges). The normals are cached on the mesh, so a scene saves them with it."""
    m = mesh.copy()
    m.merge_vertices(merge_tex=True, merge_norm=True)
    m.remove_unreferenced_vertices()
    adjacency_angles = m.face_adjacency_angles
    if len(adjacency_angles) and adjacency_angles.max() > np.radians(crease_deg):
        m = trimesh.graph.smooth_shade(m, angle=np.radians(crease_deg), facet_minarea=None)
    normals = trimesh.geometry.weighted_vertex_normals(
        vertex_count=len(m.vertices), faces=m.faces, face_normals=m.face_normals, face_angles=m.face_angles)
    out = trimesh.Trimesh(m.vertices, m.faces, vertex_normals=normals, process=False)
    return out


def check_units(meshes: dict[str, tuple[str, trimesh.Trimesh]], units: str) -> None:
    """Refuse sizes implausible for ``units`` (``meshes``: name -> (class, mesh in file units)):
    a liver must be 20-500 mm across (the largest side of its bounding box), a scene without a
    liver 20-2000 mm. The error names the unit that would fit."""
    livers = [m for c, m in meshes.values() if c == "liver"]
    parts = livers or [m for _, m in meshes.values()]
    lo = np.min([m.bounds[0] for m in parts], axis=0)
    hi = np.max([m.bounds[1] for m in parts], axis=0)
    across = float(np.max(hi - lo))  # file units
    low, high = LIVER_ACROSS_MM if livers else SCENE_ACROSS_MM
    what = "the liver" if livers else "the scene"
    size_mm = across * UNITS[units]
    if low <= size_mm <= high:
        return
    fits = [u for u, f in UNITS.items() if low <= across * f <= high]
    hint = f"; the files are probably in {fits[0]} (--units {fits[0]})" if fits else ""
    raise UserError(f"{what} is {size_mm:.4g} mm across with --units {units}, not {low:g}-{high:g} mm{hint}")


def scale_mesh(mesh: trimesh.Trimesh, factor: float) -> trimesh.Trimesh:
    """``mesh`` scaled by ``factor`` (to mm), keeping loaded vertex normals."""
    if factor == 1.0:
        return mesh
    normals = mesh._cache["vertex_normals"] if has_vertex_normals(mesh) else None
    out = trimesh.Trimesh(np.asarray(mesh.vertices) * factor, mesh.faces, process=False)
    if normals is not None:
        out = trimesh.Trimesh(out.vertices, out.faces, vertex_normals=normals, process=False)
    return out


def parse_vector(text: str, n: int, what: str) -> np.ndarray:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != n or not np.all(np.isfinite(values)):
        raise UserError(f"{what} must be {n} comma-separated finite numbers, got '{text}'")
    return np.array(values)
