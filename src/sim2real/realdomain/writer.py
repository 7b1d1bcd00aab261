"""The stand-in real domain as a dataset folder: images, palette label PNGs, sequences, manifest.

:func:`make_real_domain` renders random views and smooth sequences of simulated scenes with the
stand-in renderer (:mod:`sim2real.realdomain`) in a process pool
(:class:`sim2real.pool.WorkerPool`: one Embree ray caster and the materials per scene and
worker). Every frame draws its own seeds (:func:`~sim2real.realdomain.derive_seed`), so
the output does not depend on the number of workers. Layout: docs/realdomain.md.

Label PNGs hold the class label id per pixel (0 liver, 1 fat, 2 ligament, 3 abdominal_wall,
4 gallbladder, others from the scenes' class tables) and :data:`LABEL_BACKGROUND` = 255
for pixels without a surface (or outside the endoscope mask). They are palette PNGs: reading
them as arrays gives the indices, image viewers show the class tables' palette colours.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image
from tqdm import tqdm

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_bytes, atomic_write_image, atomic_write_json, staged_output_dir
from sim2real.pool import WorkerPool
from sim2real.realdomain.appearance import Appearance, derive_seed
from sim2real.realdomain.materials import SceneMaterial
from sim2real.realdomain.shading import RenderOptions, render_frame
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import check_fov, check_size
from sim2real.scene.classes import LABEL_BACKGROUND, ClassTable
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import make_trajectory, sample_poses

FORMAT = "sim2real-realdomain/1"

# Tags of derived seeds (see :func:`derive_seed`).
_APPEARANCE, _POSE, _TRAJECTORY, _FRAME, _SEQUENCE_FRAME = 11, 12, 13, 14, 15


def write_label(path: str | os.PathLike, label: np.ndarray, table: ClassTable | None = None) -> None:
    """Palette PNG: array values are the class label ids, viewers show the palette of ``table``
    (default: the default class table)."""
    pal = (table if table is not None else ClassTable.defaults()).palette_lut()
    im = Image.fromarray(np.ascontiguousarray(label.astype(np.uint8)), mode="P")
    im.putpalette(pal.reshape(-1).tolist())
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


# --- many frames, a process pool, deterministic per frame --------------------------------------


class WorkerScenes:
    """A worker's state: the scenes' ray casters and materials, each built on its first frame."""

    def __init__(self, scene_dirs: list[str], appearances: list[dict], options: dict):
        self.dirs = scene_dirs
        self.appearances = [Appearance(**{k: tuple(v) if isinstance(v, list) else v for k, v in a.items()})
                            for a in appearances]
        self.options = RenderOptions(**options)
        self.scenes: dict = {}

    def scene(self, k: int):
        if k not in self.scenes:
            scene = Scene.load(self.dirs[k])
            self.scenes[k] = (RayCaster(scene), SceneMaterial(scene, self.appearances[k]))
        return self.scenes[k]


def render_job(state: WorkerScenes, job) -> str:
    """Render and write one frame: ``job`` = (scene index, camera, noise seed, image path, label path)."""
    k, camera, seed, image_path, label_path = job
    caster, material = state.scene(k)
    frame = render_frame(caster.render(camera), material, state.options, seed)
    write_label(label_path, frame.label, material.scene.class_table)
    atomic_write_image(image_path, frame.image)
    return image_path


def run_jobs(scene_dirs: Sequence[str], appearances: Sequence[Appearance], options: RenderOptions, jobs: list,
             workers: int | None = None, progress: bool = True, desc: str = "realdomain") -> None:
    """Render ``jobs`` = [(scene index, camera, noise seed, image path, label path)] with a process
    pool (one Embree ray caster + materials per scene and worker); output does not depend on
    ``workers``."""
    workers = max(1, min(len(jobs), workers or os.cpu_count() or 1))
    setup_args = ([str(d) for d in scene_dirs], [a.to_json() for a in appearances], options.to_json())
    with tqdm(total=len(jobs), desc=desc, unit="frame", disable=not progress) as bar, \
            WorkerPool(workers, WorkerScenes, setup_args) as pool:
        for _ in pool.imap(render_job, jobs):
            bar.update()


def _camera_json(camera) -> dict:
    return {"K": camera.K.tolist(), "world_to_camera": camera.world_to_camera.tolist()}


def make_real_domain(
    scene_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    images: int,
    sequences: int = 0,
    frames: int = 100,
    seed: int = 0,
    height: int = 256,
    width: int = 512,
    fov_x_deg: float = 75.0,
    options: RenderOptions | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> dict:
    """Render the stand-in real domain into the new folder ``out`` and return its manifest.

    Layout::

        OUT/images/000000.png           random views (scene k % S for image k)
        OUT/labels/000000.png           class index per pixel (palette PNG, 255 = background)
        OUT/sequences/000/images/...    consecutive frames along a smooth camera path
        OUT/sequences/000/labels/...
        OUT/sequences/000/trajectory.txt
        OUT/manifest.json               seeds, parameters, appearance of each scene, every camera
    """
    if int(images) != images or images < 1:
        raise UserError(f"the number of images must be at least 1, got {images}")
    if int(sequences) != sequences or sequences < 0:
        raise UserError(f"the number of sequences must be 0 or more, got {sequences}")
    if sequences and frames < 2:
        raise UserError(f"a sequence needs at least 2 frames, got {frames}")
    if not scene_dirs:
        raise UserError("give at least one scene directory")
    check_size(height, width)
    check_fov(fov_x_deg)
    opt = options or RenderOptions()
    opt = RenderOptions(**{**opt.to_json(), "height": int(height), "width": int(width), "fov_x_deg": float(fov_x_deg)})
    for d in scene_dirs:
        if not Path(d).exists():
            raise UserError(f"scene directory {d} does not exist")
    scenes = [Scene.load(d) for d in scene_dirs]  # fails with a UserError before anything is written
    with staged_output_dir(out) as out:  # the folder appears complete, or not at all
        dirs = [str(Path(d).resolve()) for d in scene_dirs]
        appearances = [Appearance.sample(derive_seed(seed, _APPEARANCE, k)) for k in range(len(scenes))]
        casters = [RayCaster(s) for s in scenes]

        jobs, frame_entries = [], []
        for i in range(images):
            k = i % len(scenes)
            pose_seed = derive_seed(seed, _POSE, i)
            cam = sample_poses(casters[k], 1, height, width, fov_x_deg, seed=pose_seed)[0]
            name = f"{i:06d}.png"
            noise_seed = derive_seed(seed, _FRAME, i)
            jobs.append((k, cam, noise_seed, str(out / "images" / name), str(out / "labels" / name)))
            frame_entries.append({"image": f"images/{name}", "label": f"labels/{name}", "scene": k,
                                  "pose_seed": pose_seed, "noise_seed": noise_seed, **_camera_json(cam)})
        seq_entries = []
        for j in range(sequences):
            k = j % len(scenes)
            traj_seed = derive_seed(seed, _TRAJECTORY, j)
            traj = make_trajectory(casters[k], frames, height, width, fov_x_deg, seed=traj_seed)
            sdir = out / "sequences" / f"{j:03d}"
            traj.save(sdir / "trajectory.txt")
            entries = []
            for t, cam in enumerate(traj.cameras):
                name = f"{t:06d}.png"
                noise_seed = derive_seed(seed, _SEQUENCE_FRAME, j, t)
                jobs.append((k, cam, noise_seed, str(sdir / "images" / name), str(sdir / "labels" / name)))
                entries.append({"image": f"images/{name}", "label": f"labels/{name}", "noise_seed": noise_seed,
                                **_camera_json(cam)})
            seq_entries.append({"dir": f"sequences/{j:03d}", "scene": k, "trajectory_seed": traj_seed,
                                "trajectory": f"sequences/{j:03d}/trajectory.txt", "fps": traj.fps, "frames": entries})
        del casters

        run_jobs(dirs, appearances, opt, jobs, workers=workers, progress=progress)

        table = scenes[0].class_table
        for other in scenes[1:]:
            table = table.merged(other.class_table, " of the stand-in domain")
        manifest = {
            "format": FORMAT,
            "generator": "sim2real.realdomain",
            "seed": int(seed),
            "images": int(images),
            "sequences": int(sequences),
            "frames_per_sequence": int(frames) if sequences else 0,
            "render": opt.to_json(),
            "labels": {"classes": list(table.to_json()), "background": LABEL_BACKGROUND,
                       "palette": table.palette_json(), "class_table": table.to_json()},
            "scenes": [
                {"dir": d, "name": s.name, "scene_seed": s.metadata.get("seed"), "appearance": a.to_json()}
                for d, s, a in zip(dirs, scenes, appearances)
            ],
            "frames": frame_entries,
            "sequence_list": seq_entries,
        }
        atomic_write_json(out / "manifest.json", manifest)
        return manifest
