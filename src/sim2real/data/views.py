"""Folders of rendered views: ``view_00000.npz ...`` plus ``views.json``.

``views.json`` is written last, so a folder without it is an unfinished render.
"""

from __future__ import annotations

import os
from pathlib import Path

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, read_json

MANIFEST = "views.json"
FORMAT = "sim2real-views/1"


def write_views_manifest(directory: str | os.PathLike, scene_name: str, scene_dir: str | os.PathLike, count: int) -> None:
    atomic_write_json(
        Path(directory) / MANIFEST,
        {"format": FORMAT, "scene": scene_name, "scene_dir": str(Path(scene_dir).resolve()), "count": int(count)},
    )


def list_views(directory: str | os.PathLike) -> tuple[dict, list[Path]]:
    """Manifest and sorted view files of a views folder; refuses incomplete folders."""
    directory = Path(directory)
    manifest_path = directory / MANIFEST
    if not manifest_path.is_file():
        raise UserError(f"{directory} is not a finished views folder (no {MANIFEST}); render it with 'sim2real render'")
    manifest = read_json(manifest_path, "views manifest")
    if manifest.get("format") != FORMAT or not isinstance(manifest.get("count"), int):
        raise UserError(f"{manifest_path} is not a views manifest of sim2real (format {FORMAT} with a count)")
    files = sorted(directory.glob("view_*.npz"))
    if len(files) != manifest["count"]:
        raise UserError(f"{directory}: views.json lists {manifest.get('count')} views but {len(files)} view files exist")
    return manifest, files
