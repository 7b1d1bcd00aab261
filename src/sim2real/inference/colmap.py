"""The ground truth as a COLMAP model, so that tools which start from COLMAP's output (3D Gaussian
splatting, NeRF trainers, multi-view stereo) take the exact cameras instead of estimated ones::

    colmap/
      images/000000.png     the video's frames (hard links to ``tum/rgb/``)
      sparse/0/cameras.txt  PINHOLE cameras: one, or one per frame when K varies
      sparse/0/images.txt   per frame its world-to-camera pose and its 2-D observations
      sparse/0/points3D.txt surface points sampled from the ray-cast G-buffers, coloured by the frame
      README.txt

COLMAP's text format (colmap.github.io/format.html) is written here directly: it is three short
tables, unchanged since COLMAP 3.0, while pycolmap's Python API for building a model changed
between releases (rigs and frames in 3.12) and its wheel is 38 MB. COLMAP puts the centre of the
top-left pixel at (0.5, 0.5), as the project does, so ``cx, cy`` are the project's K unchanged.
Lengths are the project's millimetres.

The points are not a reconstruction: each is a ray-cast surface point of one frame, on a pixel
grid, observed in that frame only (its track has one element, its reprojection error is 0).
:func:`colmap_sampler` keeps at most about ``POINTS_BUDGET`` of them over a video of any length.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from sim2real.fileio import atomic_write_text, link_or_copy
from sim2real.footage.decode import read_image
from sim2real.inference.surface_points import PointSampler
from sim2real.scene.camera import rotation_to_quaternion

GRID_STEP = 8
"""Pixel step of the grid each frame's points are taken from before thinning."""
POINTS_BUDGET = 100_000
"""Most points the model keeps; a long video's frames are thinned evenly to stay under it."""


def colmap_sampler() -> PointSampler:
    """The sampler of the model's points; each frame adds its ``points`` (H, W, 3), mm."""
    return PointSampler(POINTS_BUDGET, GRID_STEP)


def write_colmap(folder: Path, Ks: Sequence[np.ndarray], w2c: Sequence[np.ndarray], width: int, height: int,
                 images: Sequence[Path], points: PointSampler) -> None:
    """Write ``folder`` (``colmap/``) for frames with intrinsics ``Ks``, world-to-camera poses
    ``w2c`` (mm, as COLMAP stores them) and RGB files ``images`` (hard-linked into ``images/``)."""
    n = len(Ks)
    constant_K = all(np.array_equal(K, Ks[0]) for K in Ks)
    camera_of = [1] * n if constant_K else list(range(1, n + 1))
    cams = Ks[:1] if constant_K else Ks
    cameras = ["# Camera list with one line of data per camera:",
               "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
               f"# Number of cameras: {len(cams)}"]
    cameras += [f"{c} PINHOLE {width} {height} {K[0, 0]:.10g} {K[1, 1]:.10g} {K[0, 2]:.10g} {K[1, 2]:.10g}"
                for c, K in enumerate(cams, start=1)]

    image_rows, point_rows, point_id = [], [], 1
    for i in range(n):
        name = f"{i:06d}" + images[i].suffix.lower()
        link_or_copy(images[i], folder / "images" / name)
        qx, qy, qz, qw = rotation_to_quaternion(w2c[i][:3, :3])
        tx, ty, tz = w2c[i][:3, 3]
        image_rows.append(f"{i + 1} {qw:.12g} {qx:.12g} {qy:.12g} {qz:.12g} {tx:.10g} {ty:.10g} {tz:.10g} "
                          f"{camera_of[i]} {name}")
        rows, cols, fields = points.frame(i)
        xyz = fields["points"].astype(np.float64) if len(rows) else np.zeros((0, 3))
        colours = read_image(images[i])[rows, cols] if len(rows) else np.zeros((0, 3), np.uint8)
        ids = range(point_id, point_id + len(rows))
        # Observations at the sampled pixels' centres (COLMAP's and the project's (col + 0.5, row + 0.5)).
        image_rows.append(" ".join(f"{c + 0.5:g} {r + 0.5:g} {p}" for r, c, p in zip(rows, cols, ids)))
        point_rows += [f"{p} {x:.4f} {y:.4f} {z:.4f} {R} {G} {B} 0 {i + 1} {j}"
                       for j, (p, (x, y, z), (R, G, B)) in enumerate(zip(ids, xyz, colours))]
        point_id += len(rows)

    sparse = folder / "sparse" / "0"
    atomic_write_text(sparse / "cameras.txt", "\n".join(cameras) + "\n")
    atomic_write_text(sparse / "images.txt", "\n".join([
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {n}, mean observations per image: {(point_id - 1) / n:g}",
    ] + image_rows) + "\n")
    atomic_write_text(sparse / "points3D.txt", "\n".join([
        "# 3D point list with one line of data per point:",
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
        f"# Number of points: {point_id - 1}, mean track length: 1",
    ] + point_rows) + "\n")
    atomic_write_text(folder / "README.txt", "\n".join([
        "COLMAP model exported by sim2real: the exact cameras of the video, not estimated ones",
        "",
        f"images/: the video's {n} frames, {width}x{height} pixels",
        "sparse/0/cameras.txt: PINHOLE fx fy cx cy, the centre of the top-left pixel at (0.5, 0.5)"
        + ("" if constant_K else "; one camera per frame (the intrinsics vary)"),
        "sparse/0/images.txt: world-to-camera rotation (QW QX QY QZ) and translation, millimetres,",
        "        camera axes x right, y down, z forward (OpenCV, as COLMAP)",
        f"sparse/0/points3D.txt: {point_id - 1} ray-cast surface points (millimetres), each seen in the one",
        "        frame it was sampled from, coloured by that frame; error 0",
    ]) + "\n")
