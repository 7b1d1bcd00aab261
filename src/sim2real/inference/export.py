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
      ground_truth.json       manifest; written last (its presence marks a complete export)

Units: the project's own files use millimetres (``depth/`` in 0.1 mm steps). The ``tum/``
folder follows the TUM RGB-D benchmark exactly (groundtruth in metres, depth PNG value =
metres * 5000, i.e. 0.2 mm steps; intrinsics with pixel centres at integer coordinates), so
that SLAM code written for TUM RGB-D runs on it unchanged. docs/formats.md ("Ground-truth
export") is the full description.

Saturation: a 16-bit depth PNG holds at most 65535, i.e. 6553.5 mm (``depth/``) or 13107 mm
(``tum/depth``). Deeper surfaces are written as 65535 ("this far or further"); the float
``depth_npy/`` files are exact. Surface pixels closer than half a step are written as 1 so that
0 always means "no surface".
"""

from __future__ import annotations

import io
import os
import shutil
import struct
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from PIL import Image

from sim2real.errors import UserError
from sim2real.fileio import atomic_path, atomic_write_bytes, atomic_write_image, atomic_write_json, atomic_write_text
from sim2real.render.gbuffer import GBuffer
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.render.warp import flow as gt_flow
from sim2real.scene.camera import invert_rigid, rotation_to_quaternion
from sim2real.scene.classes import LABEL_BACKGROUND, ClassTable
from sim2real.scene.tum import read_tum
from sim2real.threads import worker_count

FORMAT = "sim2real-ground-truth/1"
DEPTH_PNG_SCALE = 10.0
"""``depth/*.png`` value per millimetre (units of 0.1 mm)."""
TUM_DEPTH_SCALE = 5000.0
"""``tum/depth/*.png`` value per metre (the TUM RGB-D convention; units of 0.2 mm)."""
FLO_MAGIC = 202021.25
"""First float of a Middlebury .flo file (the bytes read 'PIEH')."""

CONVENTION = (
    "OpenCV pinhole camera: x right, y down, z forward; [u, v, 1]^T ~ K (R X + t) with "
    "world_to_camera = [R t; 0 1]. In K (the project's convention) the centre of pixel "
    "(col, row) is at (u, v) = (col + 0.5, row + 0.5). K_integer_centres has cx, cy reduced by "
    "0.5: the same camera for tools whose pixel centres are at integer coordinates (OpenCV, "
    "TUM RGB-D, ORB-SLAM). Lengths in millimetres."
)

# Names this export writes into OUT; an existing one means an earlier export is there.
_OUTPUTS = ("depth", "depth_npy", "flow", "flow_mask", "labels", "labels_color", "intrinsics.json",
            "poses_tum_mm.txt", "tum", "ground_truth.json")


def _name(i: int, ext: str) -> str:
    return f"{i:06d}.{ext}"


# --- depth ---------------------------------------------------------------------------------------


def depth_to_png16(depth_mm: np.ndarray, scale: float) -> np.ndarray:
    """Float depth (mm, 0 = no surface) -> uint16 ``round(depth_mm * scale)``; saturates at 65535,
    surface pixels never become 0."""
    d = np.nan_to_num(np.asarray(depth_mm, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    surface = d > 0
    q = np.clip(np.rint(d * scale), 0, 65535)
    q[surface & (q < 1)] = 1
    q[~surface] = 0
    return q.astype(np.uint16)


def _png16_bytes(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image, dtype=np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def read_depth_png(path: str | os.PathLike, scale: float = DEPTH_PNG_SCALE) -> np.ndarray:
    """A 16-bit depth PNG -> float32 z-depth in mm (0 = no surface). ``scale`` is the PNG value per
    millimetre: 10 for ``depth/`` (default), 5 for ``tum/depth/`` (5000 per metre)."""
    try:
        with Image.open(path) as im:
            a = np.array(im)
    except (OSError, ValueError) as e:
        raise UserError(f"cannot read depth image {path}: {e}") from None
    if a.ndim != 2 or a.dtype not in (np.uint16, np.int32, np.uint8):
        raise UserError(f"{path} is not a single-channel 16-bit depth PNG")
    return (a.astype(np.float64) / scale).astype(np.float32)


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


# --- Middlebury .flo -----------------------------------------------------------------------------


def write_flo(path: str | os.PathLike, flow: np.ndarray) -> None:
    """Write (H, W, 2) flow (u along columns, v along rows, pixels) as Middlebury .flo:
    float32 202021.25, int32 width, int32 height, then float32 u, v interleaved row by row
    (all little-endian). Written atomically."""
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must be (H, W, 2), got {flow.shape}")
    h, w = flow.shape[:2]
    header = struct.pack("<fii", FLO_MAGIC, w, h)
    atomic_write_bytes(path, header + np.ascontiguousarray(flow, dtype="<f4").tobytes())


def read_flo(path: str | os.PathLike) -> np.ndarray:
    """Read a Middlebury .flo file -> float32 (H, W, 2)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise UserError(f"cannot read flow file {path}: {e}") from None
    if len(data) < 12:
        raise UserError(f"{path} is not a .flo file (too short)")
    magic, w, h = struct.unpack("<fii", data[:12])
    if magic != FLO_MAGIC:
        raise UserError(f"{path} is not a .flo file (magic {magic!r}, expected {FLO_MAGIC})")
    if w <= 0 or h <= 0 or len(data) != 12 + 8 * w * h:
        raise UserError(f"{path}: size {w}x{h} does not match the file length {len(data)}")
    return np.frombuffer(data, dtype="<f4", offset=12).reshape(h, w, 2).astype(np.float32)


# --- labels --------------------------------------------------------------------------------------



def labels_to_color(labels: np.ndarray, table: ClassTable | None = None) -> np.ndarray:
    """uint8 labels (255 = background) -> (H, W, 3) uint8 RGB with the palette of ``table``
    (default: the default class table)."""
    return (table if table is not None else ClassTable.defaults()).palette_lut()[labels]


# --- poses ---------------------------------------------------------------------------------------


def _pose_rows(c2w: Sequence[np.ndarray], timestamps: Sequence[float], scale: float) -> list[str]:
    rows = []
    for T, ts in zip(c2w, timestamps):
        q = rotation_to_quaternion(T[:3, :3])
        t = T[:3, 3] * scale
        rows.append(f"{ts:.6f} " + " ".join(f"{x:.9f}" for x in (*t, *q)))
    return rows


def read_tum_poses(path: str | os.PathLike) -> list[np.ndarray]:
    """Read TUM trajectory rows ``timestamp tx ty tz qx qy qz qw`` -> list of 4x4 camera_to_world
    (translation in the file's unit: mm for ``poses_tum_mm.txt``, metres for ``tum/groundtruth.txt``).
    Lines starting with '#' are skipped."""
    return [T for _, T in read_tum_poses_with_time(path)]


def read_tum_poses_with_time(path: str | os.PathLike) -> list[tuple[float, np.ndarray]]:
    """Like :func:`read_tum_poses`, with each pose's timestamp."""
    return read_tum(path, "pose file")[1]


# --- TUM folder ----------------------------------------------------------------------------------


def _link_or_copy(src: Path, dst: Path) -> None:
    """Hard-link ``src`` to ``dst`` (atomically, via a temporary name); copy across file systems."""
    with atomic_path(dst) as tmp:
        tmp.unlink()
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)


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
    ``ground_truth.json``, last).
    """
    gbuffers = list(gbuffers)
    n = len(gbuffers)
    if n == 0:
        raise UserError("nothing to export: no frames")
    if not (np.isfinite(fps) and fps > 0):
        raise UserError(f"fps must be positive, got {fps}")
    h, w = gbuffers[0].height, gbuffers[0].width
    for i, g in enumerate(gbuffers):
        if (g.height, g.width) != (h, w):
            raise UserError(f"frame {i} is {g.height}x{g.width}, frame 0 is {h}x{w}; a video has one size")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"output path {out} exists and is not a directory")
    clash = [name for name in _OUTPUTS if (out / name).exists()]
    if clash:
        raise UserError(f"{out} already holds a ground-truth export ({clash[0]}); choose another folder")
    if rgb_frames_rel is not None:
        if len(rgb_frames_rel) != n:
            raise UserError(f"{len(rgb_frames_rel)} RGB frames for {n} G-buffers")
        rgb_src = [out / p for p in rgb_frames_rel]
        missing = [p for p in rgb_src if not p.is_file()]
        if missing:
            raise UserError(f"RGB frame {missing[0]} does not exist")
    table = gbuffers[0].class_table
    for g in gbuffers[1:]:
        if g.class_table is not table:
            table = table.merged(g.class_table, " of one video")
    lut = table.palette_lut()
    out.mkdir(parents=True, exist_ok=True)

    timestamps = [i / fps for i in range(n)]
    tum = out / "tum"
    def write_frame(i: int) -> None:
        g = gbuffers[i]
        depth = np.nan_to_num(g.depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        depth[~g.mask] = 0.0
        atomic_write_bytes(out / "depth" / _name(i, "png"), _png16_bytes(depth_to_png16(depth, DEPTH_PNG_SCALE)))
        atomic_write_bytes(out / "depth_npy" / _name(i, "npy"), _npy_bytes(depth))
        labels = g.labels()
        atomic_write_image(out / "labels" / _name(i, "png"), labels)
        atomic_write_image(out / "labels_color" / _name(i, "png"), lut[labels])
        if i + 1 < n:
            f, visible = gt_flow(g, gbuffers[i + 1])
            write_flo(out / "flow" / _name(i, "flo"), f)
            atomic_write_image(out / "flow_mask" / _name(i, "png"), np.where(visible, 255, 0).astype(np.uint8))
        tum_depth = depth_to_png16(depth, TUM_DEPTH_SCALE / 1000.0)
        atomic_write_bytes(tum / "depth" / _name(i, "png"), _png16_bytes(tum_depth))
        if rgb_frames_rel is not None:
            _link_or_copy(rgb_src[i], tum / "rgb" / (f"{i:06d}" + rgb_src[i].suffix.lower()))
        else:
            atomic_write_image(tum / "rgb" / _name(i, "png"), to_uint8(reference_rendering(g)))

    # PNG/zlib encoding, numpy and fsync release the GIL: frames go to threads, by the worker rule.
    workers = worker_count(jobs=n)
    if workers == 1:
        for i in range(n):
            write_frame(i)
    else:

        with ThreadPoolExecutor(workers) as pool:
            for _ in pool.map(write_frame, range(n)):
                pass
    rgb_names = [f"rgb/{i:06d}" + (rgb_src[i].suffix.lower() if rgb_frames_rel is not None else ".png") for i in range(n)]

    # Intrinsics.
    Ks = [np.asarray(g.K, dtype=np.float64) for g in gbuffers]
    constant_K = all(np.array_equal(K, Ks[0]) for K in Ks)
    intr = {"format": "sim2real-intrinsics/1", "width": w, "height": h, **_intrinsics_entry(Ks[0]),
            "constant": constant_K, "convention": CONVENTION}
    if not constant_K:
        intr["per_frame"] = [_intrinsics_entry(K) for K in Ks]
    atomic_write_json(out / "intrinsics.json", intr)

    # Poses: the project's file (mm) and TUM's groundtruth.txt (m).
    c2w = [invert_rigid(g.world_to_camera) for g in gbuffers]
    head = ["# ground truth trajectory", "# file: 'sim2real export'"]
    mm_head = head + ["# sim2real trajectory v1", f"# width {w}", f"# height {h}"]
    if constant_K:
        mm_head.append("# K " + " ".join(f"{x:.10g}" for x in Ks[0].reshape(-1)))
    mm_head += [f"# fps {fps:g}", "# timestamp tx ty tz qx qy qz qw   (camera to world, mm)"]
    atomic_write_text(out / "poses_tum_mm.txt", "\n".join(mm_head + _pose_rows(c2w, timestamps, 1.0)) + "\n")
    m_head = head + ["# timestamp tx ty tz qx qy qz qw   (camera to world, metres)"]
    atomic_write_text(tum / "groundtruth.txt", "\n".join(m_head + _pose_rows(c2w, timestamps, 1e-3)) + "\n")

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
        },
    }
    atomic_write_json(out / "ground_truth.json", manifest)
    return manifest
