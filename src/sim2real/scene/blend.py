"""Blender ``.blend`` files, read through Blender's own Python module in a separate environment.

``bpy`` (Blender as a Python module, on the package registry) pins its Python (bpy 5.0: CPython
3.11) and numpy < 2, which the project's environment does not; so it lives in its own virtual
environment (``sim2real blend setup``, about 1 GB; 134 s to install on the shared 2-core dev
machine) and runs as a subprocess: it opens the ``.blend`` file and exports every mesh object
as glTF binary (GLB) with object names, modifiers applied, world transforms and Blender's
Z-up kept (``export_yup=False``). The GLB is then read like any other mesh file. A camera's
animated path is read the same way (:func:`blend_camera_path`).

The environment is ``$SIM2REAL_BLEND_VENV``, default ``~/.cache/sim2real/blend-venv``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from sim2real.errors import UserError

BPY_REQUIREMENT = "bpy==5.0.1"
"""The bpy release set up (the newest whose wheels support CPython 3.11 on Linux x86-64)."""
BPY_PYTHON = (3, 11)
SETUP_HINT = "reading .blend files needs Blender's Python module: run 'sim2real blend setup' once (about 1 GB)"

_EXPORT = r"""
import sys
import bpy

blend, glb = sys.argv[1], sys.argv[2]
try:
    bpy.ops.wm.open_mainfile(filepath=blend)
except RuntimeError as e:
    print(f"cannot open {blend}: {str(e).strip().splitlines()[-1]}", file=sys.stderr)
    sys.exit(3)
meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
if not meshes:
    print(f"{blend} holds no mesh objects", file=sys.stderr)
    sys.exit(3)
bpy.ops.export_scene.gltf(filepath=glb, export_format="GLB", export_yup=False, export_apply=True,
                          use_selection=False, export_materials="NONE", export_animations=False)
"""

_CAMERA = r"""
import sys
import bpy

blend, out, name = sys.argv[1], sys.argv[2], sys.argv[3]
try:
    bpy.ops.wm.open_mainfile(filepath=blend)
except RuntimeError as e:
    print(f"cannot open {blend}: {str(e).strip().splitlines()[-1]}", file=sys.stderr)
    sys.exit(3)
scene = bpy.context.scene
cam = bpy.data.objects.get(name) if name else scene.camera
if cam is None or cam.type != "CAMERA":
    print(f"{blend} holds no camera object '{name}'" if name else f"{blend} has no scene camera: name one with --camera",
          file=sys.stderr)
    sys.exit(3)
c, r = cam.data, scene.render
if c.type != "PERSP":
    print(f"camera '{cam.name}' of {blend} is {c.type.lower()}, not a perspective camera", file=sys.stderr)
    sys.exit(3)
fps = r.fps / r.fps_base
scale = r.resolution_percentage / 100.0
lines = [f"# blender-camera lens_mm {c.lens!r} sensor_width_mm {c.sensor_width!r} sensor_height_mm {c.sensor_height!r} "
         f"sensor_fit {c.sensor_fit} shift_x {c.shift_x!r} shift_y {c.shift_y!r} width {round(r.resolution_x * scale)} "
         f"height {round(r.resolution_y * scale)} pixel_aspect {r.pixel_aspect_x / r.pixel_aspect_y!r}"]
for f in range(scene.frame_start, scene.frame_end + 1, scene.frame_step):
    scene.frame_set(f)
    loc, rot, _ = cam.matrix_world.decompose()
    lines.append(" ".join(f"{x!r}" for x in ((f - scene.frame_start) / fps, *loc, rot.x, rot.y, rot.z, rot.w)))
with open(out, "w") as fh:
    fh.write("\n".join(lines) + "\n")
"""


def venv_dir() -> Path:
    return Path(os.environ.get("SIM2REAL_BLEND_VENV") or Path.home() / ".cache" / "sim2real" / "blend-venv")


def venv_python() -> Path | None:
    """The bpy environment's interpreter, or None when it is not set up."""
    exe = venv_dir() / "bin" / "python"
    return exe if exe.is_file() and (venv_dir() / ".sim2real-bpy-ok").is_file() else None


def _base_python() -> str:
    if sys.version_info[:2] == BPY_PYTHON:
        return sys.executable
    found = shutil.which(f"python{BPY_PYTHON[0]}.{BPY_PYTHON[1]}")
    if found is None:
        raise UserError(f"{BPY_REQUIREMENT} needs Python {BPY_PYTHON[0]}.{BPY_PYTHON[1]}, which is not installed here; "
                        f"install it (e.g. python3.11 from your package manager) and run 'sim2real blend setup' again")
    return found


def setup() -> Path:
    """Create the bpy environment (pip shows its own progress); returns its folder."""
    target = venv_dir()
    if venv_python() is not None:
        return target
    base = _base_python()
    target.parent.mkdir(parents=True, exist_ok=True)
    # A venv records its own path, so it is built at its final place; the marker file, written
    # last, says it is complete (a half-built one is removed, or rebuilt on the next setup).
    try:
        if target.exists():
            shutil.rmtree(target)
        for cmd in ([base, "-m", "venv", str(target)],
                    [str(target / "bin" / "python"), "-m", "pip", "install", BPY_REQUIREMENT]):
            if subprocess.run(cmd).returncode != 0:
                raise UserError(f"setting up Blender's Python module failed in '{' '.join(cmd[:4])} ...'; "
                                f"see pip's output above")
        check = subprocess.run([str(target / "bin" / "python"), "-c", "import bpy"], capture_output=True, text=True)
        if check.returncode != 0:
            raise UserError(f"bpy does not import in {target}: {check.stderr.strip().splitlines()[-1:]}")
        (target / ".sim2real-bpy-ok").write_text(BPY_REQUIREMENT + "\n")
    except BaseException:
        shutil.rmtree(target, ignore_errors=True)
        raise
    return target


def _run_into(script: str, blend, out, *args: str, failure: str) -> None:
    """Run a bpy ``script`` on ``blend`` that writes ``out``; its exit status 3 is a refusal with
    its last stderr line as the message, any other failure ``failure: <last line>``."""
    r = run_script(script, str(blend), str(out), *args)
    if r.returncode == 3:
        raise UserError(r.stderr.strip().splitlines()[-1])
    if r.returncode != 0 or not Path(out).is_file():
        tail = (r.stderr.strip().splitlines() or ["no output"])[-1]
        raise UserError(f"{failure}: {tail}")


def blend_to_glb(blend: str | os.PathLike, glb: str | os.PathLike) -> None:
    """Export the mesh objects of ``blend`` to ``glb`` with bpy in its own environment."""
    _run_into(_EXPORT, blend, glb, failure=f"Blender could not export {blend}")


def blend_camera_path(blend: str | os.PathLike, out: str | os.PathLike, camera: str | None = None) -> None:
    """Write the path of ``blend``'s scene camera (or the camera object ``camera``) over the
    scene's frame range to ``out`` as TUM rows (camera to world in Blender's units and camera
    axes, seconds at the scene's frame rate), after one comment line with the camera's lens,
    sensor, shift and render size (:func:`sim2real.scene.pose_import.blender_intrinsics`)."""
    _run_into(_CAMERA, blend, out, camera or "", failure=f"Blender could not read the camera of {blend}")


def run_script(script: str, *args: str) -> subprocess.CompletedProcess:
    """Run a Python ``script`` with bpy (tests build .blend files this way)."""
    exe = venv_python()
    if exe is None:
        raise UserError(SETUP_HINT)
    return subprocess.run([str(exe), "-c", script, *map(str, args)], capture_output=True, text=True)
