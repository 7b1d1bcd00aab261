"""Where the simulated views of training come from: ``--scenes`` entries -> :class:`SceneSource`.

``--scenes`` entries are either scene folders (``scene.json``) or views folders
(``views.json`` naming their ``scene_dir``):

* a **views folder** gives cached G-buffers; each step draws two different views of it;
* a **bare scene folder** gives the views of its view pool when ``data.view_pool`` > 0 (the
  presets for a GPU: a fixed set of random poses ray-cast once into a memory-mapped cache,
  data/viewpool.py, attached by :func:`sim2real.data.viewpool.attach_view_pools`), else unlimited
  fresh random views: each step ray-casts new random poses
  (:func:`sim2real.scene.trajectory.sample_poses`) in the loader worker.

Several views folders of the same scene are merged.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim2real.data.views import MANIFEST, list_views
from sim2real.errors import UserError
from sim2real.render.gbuffer import GBuffer
from sim2real.scene.classes import ClassTable
from sim2real.scene.scene import Scene

if TYPE_CHECKING:
    from sim2real.data.viewpool import ViewPool


@dataclass
class SceneSource:
    """One scene of the training set and where its views come from."""

    name: str
    scene_dir: Path
    classes: tuple[str, ...]
    bounds: np.ndarray
    """(O, 2, 3) object bounding boxes (mm): the texture planes span them."""
    view_files: list[Path] | None = None
    """Cached G-buffers, or None to ray-cast fresh random views."""
    class_table: ClassTable | None = None
    """Label ids and a_ref colours of the scene's classes (None: the defaults)."""
    pool: "ViewPool | None" = None
    """The view pool of a bare scene folder (``data.view_pool`` > 0), or None."""

    @property
    def cached(self) -> bool:
        """Whether the views come from a views folder."""
        return self.view_files is not None

    @property
    def finite(self) -> int:
        """How many views the scene has: those of its views folder or view pool; 0 for unlimited
        fresh random views."""
        if self.view_files is not None:
            return len(self.view_files)
        return 0 if self.pool is None else len(self.pool)

    def to_json(self) -> dict:
        table = self.class_table if self.class_table is not None else ClassTable.migrate(self.classes)
        return {"name": self.name, "scene_dir": str(self.scene_dir),
                "views": None if self.view_files is None else [str(p) for p in self.view_files],
                "classes": list(self.classes), "class_table": table.to_json()}


def resolve_scenes(paths: list[str | os.PathLike], height: int, width: int) -> list[SceneSource]:
    """Turn ``--scenes`` entries into sources (one per scene, in order of first mention)."""
    if not paths:
        raise UserError("no simulated scenes given (--scenes DIR...)")
    by_name: dict[str, SceneSource] = {}
    for raw in paths:
        path = Path(raw)
        if (path / MANIFEST).is_file():
            manifest, files = list_views(path)
            if not files:
                raise UserError(f"views folder {path} holds no views")
            scene_dir = Path(manifest.get("scene_dir", ""))
            if not (scene_dir / "scene.json").is_file():
                raise UserError(f"views folder {path} names scene_dir {scene_dir}, which is not a scene folder; "
                                f"the scene is needed for its object bounding boxes")
            scene = Scene.load(scene_dir)
            first = GBuffer.load(files[0])
            if (first.height, first.width) != (height, width):
                raise UserError(f"views in {path} are {first.height}x{first.width} but training uses {height}x{width} "
                                f"(render them at that size, or set data.height/data.width)")
            if tuple(first.classes) != scene.classes:
                raise UserError(f"views in {path} do not match the objects of scene '{scene.name}' in {scene_dir}")
            if first.class_table != scene.class_table:
                raise UserError(f"views in {path} were rendered with other class colours than scene '{scene.name}' "
                                f"in {scene_dir} has now; render them again")
            src = by_name.get(scene.name)
            if src is not None and not src.cached:
                raise UserError(f"scene '{scene.name}' is given both as a scene folder and as views folder {path}; give one")
            if src is None:
                by_name[scene.name] = SceneSource(scene.name, scene_dir.resolve(), scene.classes, scene.bounds(), list(files),
                                                 scene.class_table)
            else:
                src.view_files.extend(files)
        elif (path / "scene.json").is_file():
            scene = Scene.load(path)
            if scene.name in by_name:
                raise UserError(f"scene '{scene.name}' is given twice (second time: {path})")
            by_name[scene.name] = SceneSource(scene.name, path.resolve(), scene.classes, scene.bounds(), None,
                                            scene.class_table)
        elif path.is_dir():
            raise UserError(f"{path} is neither a scene folder (scene.json) nor a finished views folder ({MANIFEST})")
        else:
            raise UserError(f"scene or views folder {path} does not exist")
    for src in by_name.values():
        if src.cached and len(src.view_files) < 2:
            raise UserError(f"scene '{src.name}' has only {len(src.view_files)} cached view; "
                            f"view consistency needs at least 2 views per scene")
    return list(by_name.values())
