"""The pictures of docs/own-data.md, made from procedural data only; prints JSON of what it wrote.

A procedural scene's liver, fat and wall are written as STL files in metres (as a CT
segmentation exported for a glTF pipeline may be), with a stomach and two kidneys added; the
worked example's import (``--units m``, ``--camera-region auto``) and ``scene preview`` then
make ``docs/own_data_preview.png``. ``docs/own_data_normals.png`` shows a_ref of the same view of
a coarse STL sphere with and without smooth normals.

    .venv/bin/python benchmarks/own_data_figures.py [--out docs]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from sim2real.cli.main import main
from sim2real.fileio import atomic_write_image
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at
from sim2real.scene.procedural import generate_scene
from sim2real.scene.scene import Scene


def _run(*argv) -> None:
    code = main([str(a) for a in argv])
    if code:
        raise SystemExit(f"sim2real {' '.join(map(str, argv))} failed with {code}")


def main_(out: Path) -> dict:
    t0 = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="own_data_"))
    scene = generate_scene(0)
    meshes = work / "meshes"
    meshes.mkdir()
    names = {"liver": "Liver", "abdominal_wall": "Abdominal_wall", "fat": "Fat"}
    for o in scene.objects:
        if o.cls in names:
            m = o.mesh.copy()
            m.apply_scale(1e-3)  # metres
            m.export(meshes / f"{names[o.cls]}.stl", file_type="stl")
    lo, hi = scene.objects[scene.objects_of("liver")[0]].mesh.bounds
    extra = {"Stomach": ([hi[0] + 25.0, 0.5 * (lo[1] + hi[1]), lo[2] + 10.0], 28.0),
             "Kidney_left": ([lo[0] - 10.0, lo[1] + 10.0, lo[2] - 25.0], 20.0),
             "Kidney_right": ([hi[0] + 10.0, lo[1] - 10.0, lo[2] - 25.0], 20.0)}
    for name, (centre, radius) in extra.items():
        m = trimesh.creation.icosphere(subdivisions=3, radius=radius)
        m.apply_translation(centre)
        m.apply_scale(1e-3)
        m.export(meshes / f"{name}.stl", file_type="stl")
    args = [a for p in sorted(meshes.glob("*.stl")) for a in ("--mesh", p)]
    _run("scene", "import", *args, "--units", "m", "--camera-region", "auto", "--out", work / "scene")
    out.mkdir(parents=True, exist_ok=True)
    _run("scene", "preview", work / "scene", "--out", out / "own_data_preview.png", "--views", 4, "--frames", 4)

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=40.0)
    wall = trimesh.creation.icosphere(subdivisions=2, radius=150.0)
    wall.invert()
    sphere.export(work / "Liver.stl", file_type="stl")
    wall.export(work / "Abdominal_wall.stl", file_type="stl")
    tiles = []
    for name, flag in (("smooth", []), ("flat", ["--flat-normals"])):
        _run("scene", "import", "--mesh", work / "Liver.stl", "--mesh", work / "Abdominal_wall.stl",
             "--camera-region", "0,0,110,5,5,5", "--out", work / name, *flag)
        s = Scene.load(work / name)
        cam = Camera(intrinsics_from_fov(192, 192, 60.0), look_at(np.array([20.0, 10.0, 110.0]), np.zeros(3), s.up),
                     192, 192)
        tiles.append(to_uint8(reference_rendering(RayCaster(s).render(cam))))
    atomic_write_image(out / "own_data_normals.png", np.concatenate([tiles[1], np.zeros((192, 4, 3), np.uint8), tiles[0]], 1))
    return {"preview": str(out / "own_data_preview.png"), "normals": str(out / "own_data_normals.png"),
            "scene": json.loads((work / "scene" / "scene.json").read_text())["camera_region"],
            "seconds": round(time.perf_counter() - t0, 1)}


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("docs"))
    print(json.dumps(main_(p.parse_args().out), indent=2))
