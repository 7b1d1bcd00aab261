"""``sim2real realset``: build a real set (frames, content masks, labels, manifest) from videos and
folders of frames.

Per source: a first pass gathers the frame statistics that find the content area
(:mod:`sim2real.footage.content`; a frame folder's from at most 100 frames spread over it, a
video's from all its sampled frames, which are kept in memory up to ``buffer_mb`` so that the
second pass need not decode them again); the second pass crops every sampled frame to the
content's box, stores it with its short side at ``height`` (never enlarged), and drops what
:mod:`sim2real.footage.filters` rejects. Labelled frames are never dropped as duplicates (Dice
needs every one). The split is by source: a fraction ``held_out`` of the sources (at least one
when there are two or more) is held out, chosen by ``seed``.

Everything is written into a temporary folder beside ``out`` and renamed at the end: a failure
leaves nothing behind.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
from tqdm import tqdm

from sim2real.data.real_manifest import FORMAT, mask_file, write_manifest
from sim2real.errors import UserError
from sim2real.fileio import check_output_dir, staged_output_dir
from sim2real.footage import content, filters, highlights, labels as labelling
from sim2real.footage.decode import Source, expected_frames, find_sources, iter_frames
from sim2real.footage.undistort import Undistorter, read_calibration, stored_intrinsics
from sim2real.scene.classes import ClassTable
from sim2real.scene.scene import CLASSES, LABEL_BACKGROUND

STATS_FRAMES = 100


@dataclass
class Settings:
    height: int = 512
    """Short side of the stored frames (the largest training height planned, or more for
    circular views, whose largest 2:1 window is 0.45 of the circle's diameter high)."""
    fps: float = 5.0
    max_frames: int | None = None
    """Per source."""
    held_out: float = 0.2
    dup_distance: int = 4
    """Hamming distance (bits of 64) up to which a frame is a near-duplicate; -1 keeps all."""
    min_content: float = 0.25
    image_format: str = "jpg"
    quality: int = 95
    labels: str | None = None
    label_map: str | None = None
    class_table: str | None = None
    """A class table file (:mod:`sim2real.scene.classes`) whose classes the label map may name."""
    seed: int = 0
    buffer_mb: int = 1024
    calibration: str | None = None
    """The endoscope's calibration (JSON, :mod:`sim2real.footage.undistort`): frames are undistorted
    first, and each source reports its stored frames' pinhole intrinsics."""
    highlights: str = "keep"
    """'inpaint': specular highlights are found and painted out of every kept frame
    (:mod:`sim2real.footage.highlights`); 'keep': frames are stored as they are."""


def assign_splits(sources: list[Source], held_out: float, seed: int) -> dict[str, str]:
    """Source id -> 'train' | 'held_out' (module docstring)."""
    ids = sorted(s.id for s in sources)
    n = len(ids)
    k = 0 if n < 2 or held_out <= 0 else min(n - 1, max(1, round(held_out * n)))
    held = set(np.random.default_rng(seed).permutation(ids)[:k].tolist())
    return {i: "held_out" if i in held else "train" for i in ids}


def build_realset(srcs: list[str], out: str, settings: Settings, progress: bool = True,
                  log: Callable[[str], None] = print) -> dict:
    """Build the real set ``out`` from ``srcs``; returns its manifest."""
    s = settings
    out_path = Path(out)
    check_output_dir(out_path)
    if (s.labels is None) != (s.label_map is None):
        raise UserError("--labels and --label-map go together")
    if s.class_table is not None and s.label_map is None:
        raise UserError("--class-table names the classes of --label-map; give it with --labels and --label-map")
    table = ClassTable.from_file(s.class_table) if s.class_table else ClassTable.defaults()
    label_map = labelling.read_label_map(s.label_map, table) if s.label_map else None
    label_dir = Path(s.labels) if s.labels else None
    if label_dir is not None and not label_dir.is_dir():
        raise UserError(f"label folder {label_dir} does not exist or is not a directory")
    if s.image_format not in ("jpg", "png"):
        raise UserError(f"image format must be jpg or png, not {s.image_format}")
    if s.highlights not in highlights.MODES:
        raise UserError(f"highlights must be one of {', '.join(highlights.MODES)}, not {s.highlights}")
    undistort = Undistorter(read_calibration(s.calibration)) if s.calibration else None
    sources = find_sources(srcs)
    splits = assign_splits(sources, s.held_out, s.seed)
    with staged_output_dir(out_path) as staged:
        manifest = _build(sources, splits, staged, s, label_map, label_dir, progress, undistort)
    if len(sources) < 2:
        log("one source only: nothing is held out (the split is by source)")
    return manifest


def _frames(src: Source, s: Settings, undistort: Undistorter | None, pick: set[int] | None = None):
    """The sampled frames of ``src``, undistorted where a calibration is given."""
    for fr in iter_frames(src, s.fps, s.max_frames, pick):
        if undistort is not None:
            fr = replace(fr, image=undistort(fr.image))
        yield fr


def _first_pass(src: Source, s: Settings, progress: bool,
                undistort: Undistorter | None) -> tuple[content.FrameStats, list | None, int]:
    """Frame statistics, the sampled frames when they fit the buffer (videos), and their count."""
    stats = content.FrameStats()
    if src.kind == "frames":
        n = min(len(src.files), s.max_frames or len(src.files))
        pick = set(np.linspace(0, n - 1, min(n, STATS_FRAMES)).round().astype(int).tolist())
        for fr in _frames(src, s, undistort, pick):
            stats.add(fr.image)
        return stats, None, n
    buf, size, n = [], 0, 0
    frames = tqdm(_frames(src, s, undistort), total=expected_frames(src, s.fps, s.max_frames),
                  desc=f"{src.id}: content area", unit="frame", disable=not progress, leave=False)
    for fr in frames:
        stats.add(fr.image)
        n += 1
        if buf is not None:
            size += fr.image.nbytes
            if size <= s.buffer_mb * 2**20:
                buf.append(fr)
            else:
                buf = None
    return stats, buf, n


def _write_image(path: Path, rgb: np.ndarray, fmt: str, quality: int) -> None:
    params = [cv2.IMWRITE_JPEG_QUALITY, quality] if fmt == "jpg" else []
    ok, data = cv2.imencode("." + fmt, np.ascontiguousarray(rgb[..., ::-1]), params)
    if not ok:
        raise UserError(f"cannot encode {path}")
    path.write_bytes(data.tobytes())


def _build(sources: list[Source], splits: dict[str, str], root: Path, s: Settings, label_map, label_dir,
           progress: bool, undistort: Undistorter | None = None) -> dict:
    frames_out, source_rows = [], []
    dropped_all: Counter = Counter()
    dups = filters.DuplicateIndex(s.dup_distance)
    for src in sources:
        stats, buf, n = _first_pass(src, s, progress, undistort)
        if n == 0 or stats.n == 0:
            raise UserError(f"source {src.path} yields no frames")
        area = content.detect(stats)
        dropped: Counter = Counter()
        row = {"id": src.id, "path": str(src.path), "kind": src.kind, "split": splits[src.id],
               "frame_size": list(stats.frame_size), "box": list(area.box), "shape": area.shape,
               "content_fraction": round(area.fraction, 4), "overlay_fraction": round(area.overlay_fraction, 4),
               "mask": None, "own_mask_frames": 0, "kept": 0, "dropped": dropped}
        shares = []
        if src.kind == "video":
            row["range"] = [src.start, None if math.isinf(src.end) else src.end]
        source_rows.append(row)
        if area.fraction < s.min_content:
            dropped["small_content"] += n
            dropped_all["small_content"] += n
            continue
        h, w = content.stored_size(area.box, s.height)
        K_frames = None if undistort is None else undistort.calibration.at(*stats.frame_size)
        if K_frames is not None:
            row["intrinsics"] = stored_intrinsics(K_frames, area.box, (h, w))
        mask = content.mask_at(area, h, w)
        mask_rel = mask_file(src.id)
        row["mask"] = mask_rel
        (root / "masks").mkdir(exist_ok=True)
        cv2.imwrite(str(root / mask_rel), mask.astype(np.uint8) * 255)
        (root / "images" / src.id).mkdir(parents=True, exist_ok=True)
        frames = buf if buf is not None else _frames(src, s, undistort)
        for fr in tqdm(frames, total=n, desc=src.id, unit="frame", disable=not progress, leave=False):
            if fr.image.shape[:2] != tuple(stats.frame_size):
                raise UserError(f"frames of source {src.path} differ in size ({tuple(stats.frame_size)} and "
                                f"{fr.image.shape[:2]})")
            f_area, f_size, f_mask, mask_id = area, (h, w), mask, src.id
            own = content.frame_area(fr.image, area, stats.size)
            if own is not None:  # this frame's view differs from the source's: its own mask and box
                row["own_mask_frames"] += 1
                if own.fraction < s.min_content:
                    dropped["small_content"] += 1
                    dropped_all["small_content"] += 1
                    continue
                f_area, f_size = own, content.stored_size(own.box, s.height)
                f_mask, mask_id = content.mask_at(own, *f_size), f"{src.id}_{fr.index:06d}"
            h_, w_ = f_size
            img = f_area.crop(fr.image)
            if img.shape[:2] != (h_, w_):
                img = cv2.resize(img, (w_, h_), interpolation=cv2.INTER_AREA)
            reason = filters.exposure(img, f_mask)
            lab_rel = None
            if reason is None and label_dir is not None and fr.file is not None:
                lp = labelling.label_path(label_dir, fr.file, src.root)
                if lp is not None:
                    lab = labelling.load_label(lp, fr.image.shape[:2], label_map)
                    if undistort is not None:
                        lab = undistort(lab, labels=True)
                    lab = np.where(f_area.mask, lab, LABEL_BACKGROUND).astype(np.uint8)
                    lab = cv2.resize(f_area.crop(lab), (w_, h_), interpolation=cv2.INTER_NEAREST)
                    lab[~f_mask] = LABEL_BACKGROUND
                    lab_rel = f"labels/{src.id}/{fr.index:06d}.png"
                    (root / "labels" / src.id).mkdir(parents=True, exist_ok=True)
                    cv2.imwrite(str(root / lab_rel), lab)
            ph = filters.phash(img, f_mask) if reason is None else None
            if reason is None and lab_rel is None and dups.is_duplicate(ph):
                reason = "duplicate"
            if reason is not None:
                dropped[reason] += 1
                dropped_all[reason] += 1
                continue
            dups.add(ph)
            if own is not None:
                cv2.imwrite(str(root / mask_file(mask_id)), f_mask.astype(np.uint8) * 255)
            rel = f"images/{src.id}/{fr.index:06d}.{s.image_format}"
            entry = {"file": rel, "source": src.id, "index": fr.index, "time": fr.time, "size": [h_, w_],
                     "mask": mask_id, "phash": f"{ph:016x}", "split": splits[src.id], "label": lab_rel}
            if own is not None and K_frames is not None:  # its own box: its own principal point
                entry["intrinsics"] = stored_intrinsics(K_frames, own.box, f_size)
            if s.highlights == "inpaint":
                img, share = highlights.inpaint_highlights(img, f_mask)
                entry["highlights"] = round(share, 5)
                shares.append(share)
            _write_image(root / rel, img, s.image_format, s.quality)
            row["kept"] += 1
            frames_out.append(entry)
        if shares:
            row["highlights"] = {"median": round(float(np.median(shares)), 5), "max": round(max(shares), 5)}
    for row in source_rows:
        row["dropped"] = dict(row["dropped"])
    label_classes = label_map.classes.to_json() if label_map is not None else None
    manifest = {"format": FORMAT, "height": s.height,
                "classes": list(label_classes) if label_classes is not None else list(CLASSES),
                "label_classes": label_classes, "label_background": LABEL_BACKGROUND,
                "settings": asdict(s), "sources": source_rows, "frames": frames_out,
                "kept": len(frames_out), "dropped": {r: dropped_all.get(r, 0) for r in filters.REASONS}}
    if not frames_out:
        raise UserError("no frame was kept (every one was dropped: " +
                        ", ".join(f"{k} {v}" for k, v in manifest["dropped"].items() if v) + ")")
    write_manifest(root, manifest)
    return manifest
