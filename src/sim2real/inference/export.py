"""Ground truth beside every video, in formats that existing tools read.

:func:`export_ground_truth` writes, for G-buffers ``g_0 .. g_{T-1}`` (one per frame)::

    OUT/
      depth/000000.png        uint16 z-depth in 0.1 mm (round(depth_mm * 10)); 0 = no surface
      depth_npy/000000.npy    float32 z-depth in mm; 0 = no surface
      flow/000000.flo         Middlebury .flo, forward flow t -> t+1 in pixels (t = 0 .. T-2)
      flow_mask/000000.png    uint8, 255 = the pixel's surface point is visible in frame t+1
      labels/000000.png       uint8 class label id (liver 0, fat 1, ligament 2, abdominal_wall 3,
                              gallbladder 4, others from the scene's class table), 255 = background
      labels_color/000000.png RGB preview of the labels (the class table's palette)
      intrinsics.json         fx, fy, cx, cy, width, height, K (+ per-frame K if it varies)
      poses_tum_mm.txt        camera-to-world poses, TUM rows, millimetres
      tum/                    a TUM RGB-D sequence folder (metres, depth scale 5000)
      colmap/                 a COLMAP model: the frames, exact cameras, sampled surface points
      tracks/                 long-range point tracks: surface points' positions and visibility in every frame
      ground_truth.json       manifest; written last (its presence marks a complete export)

Units: the project's own files use millimetres (``depth/`` in 0.1 mm steps). The ``tum/``
folder follows the TUM RGB-D benchmark exactly (groundtruth in metres, depth PNG value =
metres * 5000, i.e. 0.2 mm steps; intrinsics with pixel centres at integer coordinates), so
that SLAM code written for TUM RGB-D runs on it unchanged; ``colmap/``
(:mod:`sim2real.inference.colmap`) is for tools that start from COLMAP's output; ``tracks/``
(:mod:`sim2real.inference.tracks`) is for point trackers. docs/formats.md ("Ground-truth
export") is the full description.

Saturation: a 16-bit depth PNG holds at most 65535, i.e. 6553.5 mm (``depth/``) or 13107 mm
(``tum/depth``). Deeper surfaces are written as 65535 ("this far or further"); the float
``depth_npy/`` files are exact. Surface pixels closer than half a step are written as 1 so that
0 always means "no surface".
"""

from __future__ import annotations

import collections
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Sequence

import numpy as np

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_bytes, atomic_write_image, atomic_write_json, atomic_write_text, link_or_copy
from sim2real.inference.colmap import colmap_sampler, write_colmap
from sim2real.inference.gt_formats import (
    DEPTH_PNG_SCALE,
    TUM_DEPTH_SCALE,
    depth_to_png16,
    labels_to_color,
    npy_bytes,
    png16_bytes,
    pose_rows,
    write_flo,
)
from sim2real.inference.tracks import point_tracks, tracks_sampler, write_tracks
from sim2real.render.gbuffer import GBuffer
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.render.warp import flow as gt_flow
from sim2real.scene.camera import invert_rigid
from sim2real.scene.classes import LABEL_BACKGROUND, ClassTable
from sim2real.threads import worker_count

FORMAT = "sim2real-ground-truth/1"
CONVENTION = (
    "OpenCV pinhole camera: x right, y down, z forward; [u, v, 1]^T ~ K (R X + t) with "
    "world_to_camera = [R t; 0 1]. In K (the project's convention) the centre of pixel "
    "(col, row) is at (u, v) = (col + 0.5, row + 0.5). K_integer_centres has cx, cy reduced by "
    "0.5: the same camera for tools whose pixel centres are at integer coordinates (OpenCV, "
    "TUM RGB-D, ORB-SLAM). Lengths in millimetres."
)

# Names this export writes into OUT; an existing one means an earlier export is there.
_OUTPUTS = ("depth", "depth_npy", "flow", "flow_mask", "labels", "labels_color", "intrinsics.json",
            "poses_tum_mm.txt", "tum", "colmap", "tracks", "ground_truth.json")


def _name(i: int, ext: str) -> str:
    return f"{i:06d}.{ext}"


# --- TUM folder ----------------------------------------------------------------------------------


def _integer_centre_K(K: np.ndarray) -> np.ndarray:
    K2 = np.array(K, dtype=np.float64)
    K2[0, 2] -= 0.5
    K2[1, 2] -= 0.5
    return K2


def _intrinsics_entry(K: np.ndarray) -> dict:
    K = np.asarray(K, dtype=np.float64)
    return {
        "fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
        "K": K.tolist(), "K_integer_centres": _integer_centre_K(K).tolist(),
    }


def _tum_readme(n: int, fps: float, K_tum: np.ndarray, w: int, h: int, rgb_source: str, constant_K: bool) -> str:
    fx, fy, cx, cy = K_tum[0, 0], K_tum[1, 1], K_tum[0, 2], K_tum[1, 2]
    lines = [
        "TUM RGB-D sequence exported by sim2real (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats)",
        "",
        f"frames: {n}, {fps:g} fps, {w}x{h} pixels; timestamps are frame / fps in seconds",
        f"rgb/: {rgb_source}",
        "depth/: 16-bit PNG, value = z-depth in metres * 5000 (0.2 mm steps), 0 = no surface,",
        "        65535 = 13.107 m or further (saturated)",
        "groundtruth.txt: timestamp tx ty tz qx qy qz qw, pose of the camera's optical centre in the",
        "        world frame (camera to world), metres; camera axes x right, y down, z forward",
        "rgb.txt, depth.txt, associations.txt ('t rgb/x.png t depth/x.png', as ORB-SLAM reads it)",
        "calibration.txt: fx fy cx cy (pinhole, no distortion; pixel centres at integer coordinates,",
        "        i.e. cx, cy are the project's K minus 0.5: u = fx * X / Z + cx for integer column u)",
        f"        fx {fx:.6f}  fy {fy:.6f}  cx {cx:.6f}  cy {cy:.6f}",
    ]
    if not constant_K:
        lines.append("WARNING: the intrinsics vary per frame; calibration.txt holds frame 0, see ../intrinsics.json")
    return "\n".join(lines) + "\n"


# --- the export ----------------------------------------------------------------------------------


def _rgb_sources(out: Path, rgb_frames_rel: Sequence[str], n: int) -> list[Path]:
    """The video's RGB frames ``rgb_frames_rel`` (relative to ``out``) as paths; every one must exist."""
    if len(rgb_frames_rel) != n:
        raise UserError(f"{len(rgb_frames_rel)} RGB frames for {n} G-buffers")
    rgb_src = [out / p for p in rgb_frames_rel]
    missing = [p for p in rgb_src if not p.is_file()]
    if missing:
        raise UserError(f"RGB frame {missing[0]} does not exist")
    return rgb_src


def export_ground_truth(
    gbuffers: Sequence[GBuffer],
    out_dir: str | os.PathLike,
    fps: float = 5.0,
    rgb_frames_rel: list[str] | None = None,
) -> dict:
    """Write the ground truth of a video's frames (one G-buffer per frame) into ``out_dir``.

    ``out_dir`` may already hold the video and its frames (anything but this export's own names,
    which are refused so that two exports never mix). ``rgb_frames_rel`` are the video's RGB
    frames as paths relative to ``out_dir`` (e.g. ``frames/000000.png``); they are hard-linked
    (or copied) into ``tum/rgb/``. Without them ``tum/rgb/`` gets the reference rendering a_ref
    of each frame, so that the TUM folder is complete. Returns the manifest (also written to
    ``ground_truth.json``, last). :class:`GroundTruthWriter` writes the same while the frames
    are still being made.
    """
    gbuffers = list(gbuffers)
    if rgb_frames_rel is not None:  # refused before anything is written
        _rgb_sources(Path(out_dir), rgb_frames_rel, len(gbuffers))
    with GroundTruthWriter(out_dir, fps, rgb_frames_rel) as writer:
        for g in gbuffers:
            writer.add(g)
        return writer.close()


class GroundTruthWriter:
    """The ground truth of a video written frame by frame, while its frames are made::

        with GroundTruthWriter(out_dir, fps, rgb_frames_rel) as gt:
            for g in gbuffers:          # in frame order
                gt.add(g)
            manifest = gt.close()

    Frame ``i``'s files are written in a thread pool (by the worker rule) as soon as frame
    ``i + 1`` arrives (its flow needs both views); at most ``2 * threads`` frames are in flight
    and only the newest G-buffer is kept, so a trajectory of any length needs neither the memory
    nor the disk for its G-buffers. :meth:`close` writes the last frame, then the files that
    need every frame (intrinsics, poses, the TUM lists, the COLMAP model, the point tracks, the
    manifest, last) and links the video's RGB frames ``rgb_frames_rel`` (as in
    :func:`export_ground_truth`), which must exist by then; without them each frame's a_ref is
    written into ``tum/rgb/`` (and the COLMAP model's points are coloured by it). A write error
    is raised at the next :meth:`add` or at :meth:`close`; an error of the caller leaves no
    manifest.
    """

    def __init__(self, out_dir: str | os.PathLike, fps: float = 5.0, rgb_frames_rel: Sequence[str] | None = None,
                 threads: int | None = None):
        if not (np.isfinite(fps) and fps > 0):
            raise UserError(f"fps must be positive, got {fps}")
        out = Path(out_dir)
        if out.exists() and not out.is_dir():
            raise UserError(f"output path {out} exists and is not a directory")
        clash = [name for name in _OUTPUTS if (out / name).exists()]
        if clash:
            raise UserError(f"{out} already holds a ground-truth export ({clash[0]}); choose another folder")
        out.mkdir(parents=True, exist_ok=True)
        self.out, self.fps = out, float(fps)
        self.rgb_frames_rel = None if rgb_frames_rel is None else list(rgb_frames_rel)
        self._threads = worker_count() if threads is None else max(1, int(threads))
        self._pool: ThreadPoolExecutor | None = None
        self._pending: collections.deque = collections.deque()
        self._last: GBuffer | None = None
        self._Ks: list[np.ndarray] = []
        self._w2c: list[np.ndarray] = []  # the G-buffers' own poses; camera-to-world derived at close
        self._table: ClassTable | None = None
        self._size: tuple[int, int] | None = None
        self._points = colmap_sampler()
        self._queries = tracks_sampler()

    def __enter__(self) -> "GroundTruthWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=exc_type is not None)
            self._pool = None

    @property
    def frames(self) -> int:
        return len(self._Ks)

    def add(self, g: GBuffer) -> None:
        """The next frame's G-buffer."""
        i = self.frames
        if self._size is None:
            self._size = (g.height, g.width)
        elif (g.height, g.width) != self._size:
            raise UserError(f"frame {i} is {g.height}x{g.width}, frame 0 is {self._size[0]}x{self._size[1]}; "
                            f"a video has one size")
        if self._table is None:
            self._table = g.class_table
        elif g.class_table is not self._table:
            self._table = self._table.merged(g.class_table, " of one video")
        self._Ks.append(np.asarray(g.K, dtype=np.float64))
        self._w2c.append(np.asarray(g.world_to_camera, dtype=np.float64))
        if self._last is not None:
            self._submit(i - 1, self._last, g)
        self._last = g

    def _submit(self, i: int, g: GBuffer, g_next: GBuffer | None) -> None:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="ground-truth")
        self._pending.append(self._pool.submit(self._write_frame, i, g, g_next))
        while self._pending and (len(self._pending) > 2 * self._threads or self._pending[0].done()):
            self._pending.popleft().result()  # a failed write raises here

    def _write_frame(self, i: int, g: GBuffer, g_next: GBuffer | None) -> None:
        # PNG/zlib encoding, numpy and file writes release the GIL: frames go to threads.
        out, tum = self.out, self.out / "tum"
        depth = np.nan_to_num(g.depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        depth[~g.mask] = 0.0
        atomic_write_bytes(out / "depth" / _name(i, "png"), png16_bytes(depth_to_png16(depth, DEPTH_PNG_SCALE)))
        atomic_write_bytes(out / "depth_npy" / _name(i, "npy"), npy_bytes(depth))
        labels = g.labels()
        atomic_write_image(out / "labels" / _name(i, "png"), labels)
        atomic_write_image(out / "labels_color" / _name(i, "png"), labels_to_color(labels, g.class_table))
        if g_next is not None:
            f, visible = gt_flow(g, g_next)
            write_flo(out / "flow" / _name(i, "flo"), f)
            atomic_write_image(out / "flow_mask" / _name(i, "png"), np.where(visible, 255, 0).astype(np.uint8))
        atomic_write_bytes(tum / "depth" / _name(i, "png"), png16_bytes(depth_to_png16(depth, TUM_DEPTH_SCALE / 1000.0)))
        if self.rgb_frames_rel is None:
            atomic_write_image(tum / "rgb" / _name(i, "png"), to_uint8(reference_rendering(g)))
        self._points.add(i, g.mask, points=g.points)
        self._queries.add(i, g.mask, points=g.points, normal=g.normal, labels=labels)

    def close(self) -> dict:
        """Finish the export: the last frame, the files of the whole video, ``ground_truth.json``
        last; returns the manifest."""
        n = self.frames
        if n == 0:
            raise UserError("nothing to export: no frames")
        out, tum, fps = self.out, self.out / "tum", self.fps
        h, w = self._size
        table = self._table
        rgb_frames_rel = self.rgb_frames_rel
        rgb_src = _rgb_sources(out, rgb_frames_rel, n) if rgb_frames_rel is not None else None
        self._submit(n - 1, self._last, None)
        while self._pending:
            self._pending.popleft().result()
        if rgb_src is not None:
            for i, src in enumerate(rgb_src):
                link_or_copy(src, tum / "rgb" / (f"{i:06d}" + src.suffix.lower()))
        timestamps = [i / fps for i in range(n)]
        rgb_names = [f"rgb/{i:06d}" + (rgb_src[i].suffix.lower() if rgb_frames_rel is not None else ".png") for i in range(n)]

        # Intrinsics.
        Ks = self._Ks
        constant_K = all(np.array_equal(K, Ks[0]) for K in Ks)
        intr = {"format": "sim2real-intrinsics/1", "width": w, "height": h, **_intrinsics_entry(Ks[0]),
                "constant": constant_K, "convention": CONVENTION}
        if not constant_K:
            intr["per_frame"] = [_intrinsics_entry(K) for K in Ks]
        atomic_write_json(out / "intrinsics.json", intr)

        # Poses: the project's file (mm) and TUM's groundtruth.txt (m).
        w2c = self._w2c
        c2w = [invert_rigid(p) for p in w2c]
        head = ["# ground truth trajectory", "# file: 'sim2real export'"]
        mm_head = head + ["# sim2real trajectory v1", f"# width {w}", f"# height {h}"]
        if constant_K:
            mm_head.append("# K " + " ".join(f"{x:.10g}" for x in Ks[0].reshape(-1)))
        mm_head += [f"# fps {fps:g}", "# timestamp tx ty tz qx qy qz qw   (camera to world, mm)"]
        atomic_write_text(out / "poses_tum_mm.txt", "\n".join(mm_head + pose_rows(c2w, timestamps, 1.0)) + "\n")
        m_head = head + ["# timestamp tx ty tz qx qy qz qw   (camera to world, metres)"]
        atomic_write_text(tum / "groundtruth.txt", "\n".join(m_head + pose_rows(c2w, timestamps, 1e-3)) + "\n")

        # TUM lists and calibration.
        depth_names = [f"depth/{_name(i, 'png')}" for i in range(n)]
        ts = [f"{t:.6f}" for t in timestamps]
        atomic_write_text(tum / "rgb.txt", "# color images\n# file: 'sim2real export'\n# timestamp filename\n"
                          + "".join(f"{t} {r}\n" for t, r in zip(ts, rgb_names)))
        atomic_write_text(tum / "depth.txt", "# depth maps\n# file: 'sim2real export'\n# timestamp filename\n"
                          + "".join(f"{t} {d}\n" for t, d in zip(ts, depth_names)))
        atomic_write_text(tum / "associations.txt", "".join(f"{t} {r} {t} {d}\n" for t, r, d in zip(ts, rgb_names, depth_names)))
        K_tum = _integer_centre_K(Ks[0])
        atomic_write_text(
            tum / "calibration.txt",
            "# fx fy cx cy (pinhole, no distortion, pixel centres at integer coordinates; depth factor 5000)\n"
            f"{K_tum[0, 0]:.6f} {K_tum[1, 1]:.6f} {K_tum[0, 2]:.6f} {K_tum[1, 2]:.6f}\n",
        )
        rgb_source = ("the video's frames (" + str(Path(rgb_frames_rel[0]).parent) + "/), hard-linked or copied"
                      if rgb_frames_rel is not None else "the reference rendering a_ref of each frame (no translated frames were given)")
        atomic_write_text(tum / "README.txt", _tum_readme(n, fps, K_tum, w, h, rgb_source, constant_K))
        write_colmap(out / "colmap", Ks, w2c, w, h, [tum / r for r in rgb_names], self._points)
        tracks = point_tracks(Ks, w2c, lambda j: np.load(out / "depth_npy" / _name(j, "npy")),
                              self._queries)
        write_tracks(out / "tracks", tracks, w, h)

        manifest = {
            "format": FORMAT,
            "frames": n,
            "fps": fps,
            "width": w,
            "height": h,
            "classes": list(table.to_json()),  # in label-id order
            "class_table": table.to_json(),
            "label_background": LABEL_BACKGROUND,
            "label_palette": table.palette_json(),
            "depth_png_per_mm": DEPTH_PNG_SCALE,
            "tum_depth_per_m": TUM_DEPTH_SCALE,
            "flow_frames": max(n - 1, 0),
            "rgb_frames": list(rgb_frames_rel) if rgb_frames_rel is not None else None,
            "files": {
                "depth": "depth/%06d.png", "depth_npy": "depth_npy/%06d.npy", "flow": "flow/%06d.flo",
                "flow_mask": "flow_mask/%06d.png", "labels": "labels/%06d.png", "labels_color": "labels_color/%06d.png",
                "intrinsics": "intrinsics.json", "poses": "poses_tum_mm.txt", "tum": "tum/",
                "colmap": "colmap/", "tracks": "tracks/tracks.npz",
            },
        }
        atomic_write_json(out / "ground_truth.json", manifest)
        return manifest
