"""``sim2real scene preview``: what the camera sees, before any training.

A contact sheet (one PNG) of the reference rendering a_ref of random training views (the
poses training draws: :func:`sim2real.scene.trajectory.sample_poses`) and of frames spread
over one 100-frame test trajectory (:func:`~sim2real.scene.trajectory.make_trajectory`), each tile
captioned with its background share (rays that escaped the scene). Rows of four tiles with a
2-pixel gap; the random views first, then the trajectory.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_image
from sim2real.render.raycast import RayCaster, check_camera_region
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.camera import check_size
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import make_trajectory, sample_poses

COLUMNS = 4
GAP = 2
TRAJECTORY_FRAMES = 100
"""Length of the previewed test trajectory (the paper's); ``frames`` of it are shown, evenly spread."""


def _caption(tile: np.ndarray, text: str) -> np.ndarray:
    im = Image.fromarray(tile)
    draw = ImageDraw.Draw(im)
    draw.rectangle([0, 0, 6 * len(text) + 4, 12], fill=(0, 0, 0))
    draw.text((2, 1), text, fill=(255, 255, 255))
    return np.asarray(im)


def sheet(tiles: list[np.ndarray], columns: int = COLUMNS) -> np.ndarray:
    """Tiles of one size in rows of ``columns``, ``GAP`` pixels of black between them."""
    h, w = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    out = np.zeros((rows * h + (rows - 1) * GAP, columns * w + (columns - 1) * GAP, 3), np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, columns)
        out[r * (h + GAP): r * (h + GAP) + h, c * (w + GAP): c * (w + GAP) + w] = t
    return out


def contact_sheet(scene_dir: str | os.PathLike, out: str | os.PathLike, views: int = 8, frames: int = 8,
                  height: int = 128, width: int = 256, fov: float = 75.0, seed: int = 0) -> Path:
    """Write the contact sheet of ``scene_dir`` to ``out`` (PNG); returns its path."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise UserError(f"the preview is a PNG file; got '{out}'")
    if out.is_dir():
        raise UserError(f"{out} is a directory; give a file name ending in .png")
    check_size(height, width)
    scene = Scene.load(scene_dir)
    caster = RayCaster(scene)
    check_camera_region(scene, caster)
    tiles = []
    for k, cam in enumerate(sample_poses(caster, views, height, width, fov, seed=seed)):
        g = caster.render(cam)
        tiles.append(_caption(to_uint8(reference_rendering(g)), f"view {k}  bg {1 - g.mask.mean():.0%}"))
    traj = make_trajectory(caster, TRAJECTORY_FRAMES, height, width, fov, seed=seed)
    picks = np.unique(np.linspace(0, len(traj.cameras) - 1, frames).round().astype(int))
    for t in picks:
        g = caster.render(traj.cameras[int(t)])
        tiles.append(_caption(to_uint8(reference_rendering(g)), f"path {t}  bg {1 - g.mask.mean():.0%}"))
    atomic_write_image(out, sheet(tiles))
    return out
