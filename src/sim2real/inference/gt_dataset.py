"""A translated video and its ground truth as a PyTorch dataset, one sample per frame, read back
from the files that ``sim2real translate`` (or :func:`~sim2real.inference.export.export_ground_truth`)
wrote: to train or test depth, flow, segmentation or pose networks on them::

    from torch.utils.data import DataLoader
    from sim2real.inference.gt_dataset import GroundTruthDataset

    data = GroundTruthDataset("video")          # a translate output, or its ground_truth/ folder
    loader = DataLoader(data, batch_size=8, shuffle=True, num_workers=4)

Sample ``i`` is a dict of tensors (H x W the video's size):

=================  ===================  ==========================================================
key                shape, dtype         what
=================  ===================  ==========================================================
image              (3, H, W) float32    frame ``i``, RGB in [0, 1] (the reference rendering a_ref
                                        where the export was given no frames)
depth              (1, H, W) float32    z-depth in mm, 0 = no surface (``depth_npy/``, unrounded)
labels             (H, W) int64         class label id (``class_names``), 255 = background
flow               (2, H, W) float32    optical flow to frame ``i + 1`` in pixels (u along
                                        columns, v along rows); zeros in the last frame
flow_mask          (H, W) bool          where ``flow`` holds: the point is seen in frame ``i + 1``;
                                        all False in the last frame
K                  (3, 3) float32       the frame's intrinsics (pixel centres at +0.5)
camera_to_world    (4, 4) float32       the camera's pose, mm, OpenCV axes (x right, y down)
index              int64 scalar         ``i``
right_image        (3, H, W) float32    with ``stereo=True``: the right eye's frame ``i``
disparity          (1, H, W) float32    with ``stereo=True``: the left pixel's disparity, pixels
                                        (its point is at ``(u - d, v)`` in the right image), 0 =
                                        no surface
disparity_mask     (H, W) bool          with ``stereo=True``: the right eye sees the point
tracks             (N, 2) float32       on request only: the (x, y) pixel position in frame ``i``
                                        of each of the video's N tracked surface points
                                        (``tracks/tracks.npz``; NaN behind the camera)
track_visible      (N,) bool            on request only: frame ``i`` sees the point
=================  ===================  ==========================================================

``fields`` names the keys to read; the others' files are not opened. The tracks' keys are read
only when named (every sample then carries all N points; the file is loaded once per process).

``clip`` makes each sample a short clip, for networks that learn from neighbouring frames
(self-supervised depth and pose, point trackers, video models): ``clip=(0, -1, 1)`` stacks frames
``i``, ``i - 1`` and ``i + 1`` along a new first dimension of every key (``image`` (3, 3, H, W),
``camera_to_world`` (3, 4, 4), ``index`` (3,)), over the centre frames whose neighbours all exist
(``len`` = frames less the clip's span).
``torch.linalg.inv(c2w[a]) @ c2w[b]`` maps points from frame ``b``'s camera to frame ``a``'s.
The formats themselves: docs/formats.md (Ground-truth export, Translate output).
"""

from __future__ import annotations

import operator
import os
import zipfile
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from PIL import Image

from sim2real.errors import UserError, reason
from sim2real.fileio import read_json
from sim2real.footage.decode import read_image
from sim2real.inference.gt_formats import read_flo, read_tum_poses
from sim2real.inference.realimages import load_label

FIELDS = ("image", "depth", "labels", "flow", "flow_mask", "K", "camera_to_world", "index")
STEREO_FIELDS = ("right_image", "disparity", "disparity_mask")
TRACK_FIELDS = ("tracks", "track_visible")


def _ground_truth_folder(root: Path) -> Path:
    for folder in (root, root / "ground_truth"):
        if (folder / "ground_truth.json").is_file():
            return folder
    raise UserError(f"{root} is neither a translate output nor a ground-truth export (no ground_truth.json "
                    "in it or in its ground_truth/)")


def _map_tensor(path: Path) -> torch.Tensor:
    """A float32 (H, W) ``.npy`` map as a (1, H, W) tensor."""
    try:
        return torch.from_numpy(np.load(path).astype(np.float32))[None]
    except (OSError, ValueError) as e:
        raise UserError(f"cannot read array {path}: {reason(e)}") from None


class GroundTruthDataset(torch.utils.data.Dataset):
    """The frames of a translate output (or a ground-truth export) with their ground truth; see the
    module's docstring for the keys. ``stereo=True`` adds the right eye of a ``translate
    --stereo`` output; ``clip`` (frame offsets) makes each sample a clip of neighbouring frames.
    Holds paths only, so that loader workers can pickle it."""

    def __init__(self, root: str | os.PathLike, fields: Sequence[str] | None = None, stereo: bool = False,
                 clip: Sequence[int] | None = None):
        self.root = _ground_truth_folder(Path(root))
        manifest = read_json(self.root / "ground_truth.json", "ground-truth manifest")
        if not str(manifest.get("format", "")).startswith("sim2real-ground-truth/"):
            raise UserError(f"{self.root / 'ground_truth.json'} is not a sim2real ground-truth manifest "
                            f"(format {manifest.get('format')!r})")
        known = FIELDS + (STEREO_FIELDS if stereo else ())
        self.fields = tuple(known if fields is None else fields)
        known += TRACK_FIELDS
        unknown = [f for f in self.fields if f not in known]
        if unknown:
            raise UserError(f"unknown field {unknown[0]!r}; choose from {', '.join(known)}"
                            + ("" if stereo else " (the right eye's with stereo=True)"))
        self.frames = int(manifest["frames"])
        self.size = (int(manifest["height"]), int(manifest["width"]))
        self.fps = float(manifest["fps"])
        self.class_names = {int(e["label"]): name for name, e in manifest["class_table"].items()}
        """Label id -> class name (255, the background, is not in it)."""
        rgb = manifest.get("rgb_frames")
        self._rgb = [self.root / p for p in rgb] if rgb else [self.root / "tum" / "rgb" / f"{i:06d}.png"
                                                              for i in range(self.frames)]
        intr = read_json(self.root / "intrinsics.json", "intrinsics file")
        Ks = [e["K"] for e in intr["per_frame"]] if "per_frame" in intr else [intr["K"]] * self.frames
        self.K = torch.tensor(np.asarray(Ks, dtype=np.float32))
        """(frames, 3, 3) every frame's intrinsics."""
        self.camera_to_world = torch.tensor(np.asarray(read_tum_poses(self.root / "poses_tum_mm.txt"), np.float32))
        """(frames, 4, 4) every frame's pose, mm."""
        if len(self.K) != self.frames or len(self.camera_to_world) != self.frames:
            raise UserError(f"{self.root}: {len(self.K)} intrinsics and {len(self.camera_to_world)} poses "
                            f"for {self.frames} frames")
        self._tracks: dict[str, np.ndarray] | None = None  # loaded at the first sample that asks
        if set(self.fields) & set(TRACK_FIELDS) and not (self.root / "tracks" / "tracks.npz").is_file():
            raise UserError(f"{self.root} holds no point tracks (no tracks/tracks.npz)")
        self.clip = None if clip is None else _clip_offsets(clip, self.frames)
        """The frame offsets of a clip sample, or None for single frames."""
        self._stereo = None
        if stereo:
            top = self.root.parent if self.root.name == "ground_truth" else self.root
            if not (top / "stereo" / "stereo.json").is_file():
                raise UserError(f"{top} holds no stereo pair (no stereo/stereo.json): translate it with --stereo MM")
            self._stereo = top
            self.baseline_mm = float(read_json(top / "stereo" / "stereo.json", "stereo file")["baseline_mm"])

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_tracks": None}  # paths only: each loader worker loads its own

    def _track(self, name: str, i: int) -> torch.Tensor:
        if self._tracks is None:
            path = self.root / "tracks" / "tracks.npz"
            try:
                with np.load(path) as f:
                    self._tracks = {"tracks": f["tracks"], "track_visible": f["visible"]}
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
                raise UserError(f"cannot read point tracks {path}: {reason(e)}") from None
        return torch.from_numpy(np.ascontiguousarray(self._tracks[name][:, i]))

    def __len__(self) -> int:
        return self.frames if self.clip is None else self.frames - (max(self.clip) - min(self.clip))

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"{'frame' if self.clip is None else 'clip'} {i} of {n}")
        i = int(i) % n
        if self.clip is None:
            return self._frame(i)
        centre = i - min(self.clip)
        frames = [self._frame(centre + k) for k in self.clip]
        return {f: torch.stack([fr[f] for fr in frames]) for f in self.fields}

    def _frame(self, i: int) -> dict[str, torch.Tensor]:
        name = f"{i:06d}"
        h, w = self.size
        read = {
            "image": lambda: _image_tensor(self._rgb[i]),
            "depth": lambda: _map_tensor(self.root / "depth_npy" / f"{name}.npy"),
            "labels": lambda: torch.from_numpy(load_label(self.root / "labels" / f"{name}.png").astype(np.int64)),
            "flow": lambda: (torch.from_numpy(read_flo(self.root / "flow" / f"{name}.flo")).permute(2, 0, 1).contiguous()
                             if i + 1 < self.frames else torch.zeros(2, h, w)),
            "flow_mask": lambda: (_mask(self.root / "flow_mask" / f"{name}.png") if i + 1 < self.frames
                                  else torch.zeros(h, w, dtype=torch.bool)),
            "K": lambda: self.K[i].clone(),
            "camera_to_world": lambda: self.camera_to_world[i].clone(),
            "index": lambda: torch.tensor(i),
            "tracks": lambda: self._track("tracks", i),
            "track_visible": lambda: self._track("track_visible", i),
        }
        if self._stereo is not None:
            top = self._stereo
            read.update({
                "right_image": lambda: _image_tensor(top / "right" / "frames" / f"{name}.png"),
                "disparity": lambda: _map_tensor(top / "stereo" / "disparity" / f"{name}.npy"),
                "disparity_mask": lambda: _mask(top / "stereo" / "disparity_mask" / f"{name}.png"),
            })
        return {f: read[f]() for f in self.fields}


def _clip_offsets(clip: Sequence[int], frames: int) -> tuple[int, ...]:
    """``clip`` as distinct integer frame offsets that fit in a video of ``frames`` frames."""
    try:
        offsets = tuple(operator.index(k) for k in clip)
    except TypeError:
        raise UserError(f"clip takes integer frame offsets such as (0, -1, 1), not {clip!r}") from None
    if not offsets or len(set(offsets)) != len(offsets):
        raise UserError(f"clip takes distinct frame offsets such as (0, -1, 1), not {clip!r}")
    span = max(offsets) - min(offsets)
    if span >= frames:
        raise UserError(f"a clip spanning {span + 1} frames needs a video of at least that many; this one has {frames}")
    return offsets


def _image_tensor(path: Path) -> torch.Tensor:
    return torch.tensor(read_image(path)).permute(2, 0, 1).float().div_(255.0)


def _mask(path: Path) -> torch.Tensor:
    """A 0/255 mask PNG as a bool tensor."""
    try:
        with Image.open(path) as im:
            return torch.from_numpy(np.array(im.convert("L")) > 127)
    except (OSError, ValueError) as e:
        raise UserError(f"cannot read mask {path}: {reason(e)}") from None
