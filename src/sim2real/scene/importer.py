"""``sim2real scene import``: a scene from the user's own mesh files.

Every input is checked before anything is written: the class of every part (from ``PATH=CLASS``,
``--class PART=CLASS`` or the part's name), the class table (the defaults, or a user's table
file), the plausibility of the sizes for the given unit, the camera region (given, or fitted
with ``auto``). Meshes are stored in millimetres; STL and OBJ meshes without vertex normals get
smooth ones (:func:`sim2real.scene.io.smooth_normals`) unless ``flat_normals``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import trimesh

from sim2real.errors import UserError
from sim2real.render.raycast import RayCaster, check_camera_region
from sim2real.render.region import fit_camera_region
from sim2real.scene.classes import ClassTable
from sim2real.scene.conventions import UNITS
from sim2real.scene.io import (
    NORMALS_SUFFIXES,
    check_mesh,
    check_units,
    class_from_name,
    has_vertex_normals,
    load_parts,
    mesh_files,
    parse_vector,
    scale_mesh,
    smooth_normals,
)
from sim2real.scene.scene import CameraRegion, Scene, SceneObject


def _mapping(items: list[str]) -> dict[str, str]:
    mapping = {}
    for item in items:
        if "=" not in item:
            raise UserError(f"--class expects PART=CLASS, got '{item}'")
        part, cls = item.split("=", 1)
        mapping[part] = cls
    return mapping


def import_scene(args: argparse.Namespace) -> Scene:
    """Build, check and save the scene of ``sim2real scene import`` (see the module docstring)."""
    table = ClassTable.from_file(args.class_table) if args.class_table else ClassTable.defaults()
    mapping = _mapping(args.classes)
    parts: dict[str, tuple[str, object, str]] = {}  # name -> (class, mesh in file units, suffix)
    for spec in [one for given in args.mesh for one in mesh_files(given)]:
        path, _, cls = spec.partition("=")
        suffix = Path(path).suffix.lower()
        if cls:
            loaded = load_parts(path)
            mesh = next(iter(loaded.values())) if len(loaded) == 1 else trimesh.util.concatenate(list(loaded.values()))
            check_mesh(mesh, Path(path).stem)
            items = [(Path(path).stem, cls, mesh)]
        else:
            items = [(part, class_from_name(part, mapping, table), mesh) for part, mesh in load_parts(path).items()]
        for name, c, mesh in items:
            if name in parts:
                raise UserError(f"two meshes are named '{name}'; rename one of the files or parts")
            parts[name] = (c, mesh, suffix)
    table.subset(c for c, _, _ in parts.values())  # every class known, before any work
    check_units({n: (c, m) for n, (c, m, _) in parts.items()}, args.units)
    factor = UNITS[args.units]
    objects = []
    for name, (c, mesh, suffix) in parts.items():
        mesh = scale_mesh(mesh, factor)
        own = False
        if not args.flat_normals and suffix in NORMALS_SUFFIXES and not has_vertex_normals(mesh):
            mesh, own = smooth_normals(mesh, args.crease_angle), True
        objects.append(SceneObject(name, c, mesh, own))
    auto = args.camera_region.strip().lower() == "auto"
    region = CameraRegion([0, 0, 0], [1, 1, 1]) if auto else None
    if not auto:
        r = parse_vector(args.camera_region, 6, "--camera-region")
        region = CameraRegion(r[:3], r[3:])
    scene = Scene(
        name=args.name or Path(args.out).name,
        objects=objects,
        camera_region=region,
        up=parse_vector(args.up, 3, "--up"),
        anterior=parse_vector(args.anterior, 3, "--anterior"),
        class_table=table,
        source_units=args.units,
    )
    caster = RayCaster(scene)
    if auto:
        scene.camera_region = fit_camera_region(caster)
    check_camera_region(scene, caster)
    scene.save(args.out)
    return scene
