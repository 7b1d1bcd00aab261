"""Unlabeled real images (domain B): a real set made by ``sim2real realset`` (frames with
content masks), or a folder searched recursively for PNG/JPEG files.

Each training iteration takes one image, resizes it so that it covers ``height x width``
times a random factor in ``[scale_min, scale_max]`` (aspect ratio kept), and crops a random
``height x width`` window, as the paper does. Images of any PIL mode are converted to RGB:
grey (L, LA, 16-bit I/I;16) is repeated over the three channels, palettes are expanded, and
an alpha channel is dropped (the colour values are kept as they are, not composited).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from PIL import Image

from sim2real.data.cover import ValidArea, random_cover_crops
from sim2real.data.real_manifest import is_realset, load_mask, mask_file, read_manifest
from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, read_json_or_none

EXTENSIONS = (".png", ".jpg", ".jpeg")


def list_images(folder: str | os.PathLike, what: str = "real image") -> list[Path]:
    """Sorted image files under ``folder`` (recursive, extensions case-insensitive); ``what`` names
    them in the error of a missing or empty folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{what} folder {folder} does not exist or is not a directory")
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in EXTENSIONS and p.is_file())
    if not files:
        raise UserError(f"no {what}s (png/jpg) found under {folder}")
    return files


def verify_images(files: list[Path]) -> list[tuple[int, int]]:
    """Open every file's header and check its structure (PIL ``verify``: no full decode);
    the first unreadable one is named in a UserError. Returns each image's (height, width)."""
    sizes = []
    for path in files:
        try:
            with Image.open(path) as im:
                sizes.append((im.height, im.width))
                im.verify()
        except Exception as e:  # PIL raises many types for damaged files
            raise UserError(f"cannot read real image {path}: {e}") from None
    return sizes


ENLARGEMENT_NOTED = 1.1
"""Smallest enlargement of real frames that :func:`enlargement_note` reports (10 %: below it,
bilinear enlargement blurs less than the random scale of [1.0, 1.2] varies the crops)."""


def enlargement_note(factors: list[float], height: int, width: int) -> str | None:
    """A note when real frames are enlarged by at least :data:`ENLARGEMENT_NOTED` for the
    ``height x width`` training crop, else None; ``factors``: each frame's smallest scale factor
    (:meth:`RealImages.enlargements`). Enlarged real crops are blurrier than the generated
    images, and the translator learns that blur."""
    small = [f for f in factors if f >= ENLARGEMENT_NOTED]
    if not small:
        return None
    return (f"note: {len(small)} of {len(factors)} real frames hold less than the {height}x{width} training crop "
            f"and are enlarged (up to {max(small):.1f}x), so the translator learns their blur; give larger frames "
            f"or train smaller (--set data.height=... data.width=...)")


FOV_NOTED = 0.1
"""Relative difference between the simulated views' and the real crops' horizontal fields of
view from which :func:`field_of_view_note` speaks (10 %: organs then appear a tenth larger or
smaller in one domain than in the other)."""


def field_of_view_note(real_deg: list[float], sim_deg: float, scale_min: float, scale_max: float) -> str | None:
    """A note when the real crops' horizontal field of view (``real_deg``: each calibrated
    training frame's at crop scale 1, :meth:`RealImages.crop_fields_of_view`) differs from the
    simulated views' ``sim_deg`` by at least :data:`FOV_NOTED`, else None. A crop at scale s
    sees ``2 atan(tan(fov / 2) / s)``: the note gives the range over the scales drawn."""
    if not real_deg:
        return None
    mid = float(np.median(real_deg))

    def at(scale: float) -> float:
        return math.degrees(2 * math.atan(math.tan(math.radians(mid) / 2) / scale))

    typical = at(math.sqrt(scale_min * scale_max))
    if abs(typical - sim_deg) < FOV_NOTED * sim_deg:
        return None
    return (f"note: the real set's calibrated training crops see {at(scale_max):.1f}-{at(scale_min):.1f} degrees "
            f"across, the simulated views {sim_deg:.1f} (data.fov_x_deg or data.intrinsics), so organs appear at "
            f"other sizes in the two domains; set data.fov_x_deg={typical:.1f} or data.intrinsics")


def load_rgb(path: str | os.PathLike) -> np.ndarray:
    """Decode an image as uint8 (H, W, 3) RGB, converting grey, palette and alpha modes."""
    try:
        with Image.open(path) as im:
            im.load()
            return to_rgb(im)
    except UserError:
        raise
    except Exception as e:
        raise UserError(f"cannot read real image {path}: {e}") from None


def to_rgb(im) -> np.ndarray:
    """PIL image of any mode -> uint8 (H, W, 3)."""
    if im.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
        a = np.asarray(im, dtype=np.float64)
        scale = 1.0 if im.mode == "F" else 65535.0
        grey = np.clip(a / scale, 0.0, 1.0) * 255.0 + 0.5
        return np.repeat(grey.astype(np.uint8)[..., None], 3, axis=2)
    if im.mode == "P" and "transparency" in im.info:
        im = im.convert("RGBA")
    if im.mode != "RGB":
        im = im.convert("RGB")
    return np.asarray(im, dtype=np.uint8)


def random_resized_crop(image: np.ndarray, height: int, width: int, scale_min: float, scale_max: float,
                        rng: np.random.Generator, valid: ValidArea | None = None) -> np.ndarray:
    """Resize ``image`` (h, w, 3) uint8 by ``max(height / h, width / w) * U[scale_min, scale_max]``
    (bilinear, area-filtered when shrinking) and crop a random ``height x width`` window; inside
    the content mask ``valid`` where given (:mod:`sim2real.data.cover`)."""
    return random_cover_crops([image], height, width, scale_min, scale_max, rng, valid)[0]


def random_resized_crops(images: list[np.ndarray], height: int, width: int, scale_min: float, scale_max: float,
                         rng: np.random.Generator) -> list[np.ndarray]:
    """:func:`random_resized_crop` with one draw of scale and window for all ``images`` (frames of
    one size, e.g. consecutive frames of a sequence, which must stay aligned)."""
    return random_cover_crops(images, height, width, scale_min, scale_max, rng)


def to_network(crop: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) -> float32 (3, H, W) in [-1, 1]."""
    return (crop.astype(np.float32).transpose(2, 0, 1) / 127.5) - 1.0


INDEX = "real_index.json"
"""The index of a plain real folder that training writes into its run folder: the image files,
listed and checked once; a resumed run reads it instead of checking every image again. It is
rebuilt when the folder, or the modification time of a directory that holds its images, changed
(an image added, removed or renamed)."""
INDEX_FORMAT = "sim2real-real-index/1"


def _dir_stamps(root: Path, files: list[Path]) -> dict[str, int]:
    dirs = sorted({root, *(f.parent for f in files)})
    return {str(d.relative_to(root)): d.stat().st_mtime_ns for d in dirs}


def _read_index(path: Path, root: Path) -> list[Path] | None:
    """The files of a still valid index at ``path`` for ``root``, else None."""
    idx = read_json_or_none(path)
    if not idx or idx.get("format") != INDEX_FORMAT or idx.get("root") != str(root):
        return None
    try:
        stamps = {d: (root / d).stat().st_mtime_ns for d in idx["dirs"]}
    except (OSError, KeyError, TypeError):
        return None
    if stamps != idx["dirs"]:
        return None
    return [root / f for f in idx["files"]]


class RealImages:
    """The real-image pool (domain B) with random crops on demand, from either

    - a **real set** (``sim2real realset``; :mod:`sim2real.data.real_manifest`): its training
      split's frames, each cropped inside its source's content mask, so that no crop shows the
      endoscope's dark surround or an overlay; or
    - a **plain folder** of PNG/JPEG images (searched recursively, every image used whole). Its
      files are listed and checked once; with ``index`` (a path in the run folder, see
      :data:`INDEX`) that list is kept for the run's next start. :meth:`save_index` writes it.
    """

    def __init__(self, folder: str | os.PathLike, verify: bool = True, index: str | os.PathLike | None = None):
        self.folder = Path(folder)
        self.index_path = Path(index) if index is not None else None
        self._new_index: dict | None = None
        self.masks: list[str | None] = []
        self.sizes: list[tuple[int, int]] | None = None  # (h, w) per image; None when read from the index
        self._valid: dict[str, ValidArea] = {}
        if is_realset(self.folder):
            m = read_manifest(self.folder)
            frames = [f for f in m["frames"] if f["split"] == "train"]
            if not frames:
                raise UserError(f"the real set {self.folder} holds no training frames "
                                f"(all {len(m['frames'])} are held out)")
            self.files = [self.folder / f["file"] for f in frames]
            self.masks = [f["mask"] for f in frames]
            self.sizes = [tuple(f["size"]) for f in frames]
            calibrated = {s["id"]: s["intrinsics"] for s in m["sources"] if s.get("intrinsics")}
            self.intrinsics = [f.get("intrinsics") or calibrated.get(f["source"]) for f in frames]
            self.realset = True
            return
        self.realset = False
        self.intrinsics = []
        root = self.folder.resolve()
        cached = None
        if self.index_path is not None and self.index_path.is_file():
            cached = _read_index(self.index_path, root)
        if cached is not None:
            self.files = cached
            return
        self.files = list_images(folder)
        if verify:
            self.sizes = verify_images(self.files)
        if self.index_path is not None:
            rfiles = [f.resolve() for f in self.files]
            self._new_index = {"format": INDEX_FORMAT, "root": str(root),
                               "dirs": _dir_stamps(root, rfiles),
                               "files": [str(f.relative_to(root)) for f in rfiles]}

    def save_index(self) -> None:
        """Write the index of a plain folder listed by this construction into ``index``."""
        if self._new_index is not None and self.index_path is not None:
            atomic_write_json(self.index_path, self._new_index)
            self._new_index = None

    def __len__(self) -> int:
        return len(self.files)

    def enlargements(self, height: int, width: int) -> list[float] | None:
        """Each image's smallest scale factor for a ``height x width`` crop (None when the sizes
        are unknown: a plain folder read from its index): ``max(height / h, width / w)`` for a
        whole ``(h, w)`` image (:func:`random_resized_crop`), ``1 / k`` for a real set's frame
        whose content mask holds at most a ``k*height x k*width`` window
        (:meth:`~sim2real.data.cover.ValidArea.inscribed_scale`: a circular view holds less
        than its box)."""
        if self.sizes is None:
            return None
        if self.masks:
            return [1.0 / self.valid_area(i).inscribed_scale(height, width) for i in range(len(self.files))]
        return [max(height / h, width / w) for h, w in self.sizes]

    def crop_fields_of_view(self, height: int, width: int) -> list[float]:
        """The horizontal field of view (degrees) of each calibrated training frame's largest
        ``height x width`` window, the training crop at scale 1 (its source's intrinsics from
        ``realset --calibration``; a window centred on the principal point); empty without them."""
        out = []
        for i, K in enumerate(self.intrinsics):
            if K:
                half = 0.5 * width * self.valid_area(i).inscribed_scale(height, width)
                out.append(math.degrees(2 * math.atan(half / K[0])))
        return out

    def valid_area(self, i: int) -> ValidArea | None:
        """The content mask of image ``i`` (loaded once per mask and process), None for a plain folder."""
        if not self.masks:
            return None
        mid = self.masks[i]
        if mid not in self._valid:
            self._valid[mid] = ValidArea(load_mask(self.folder / mask_file(mid)))
        return self._valid[mid]

    def sample(self, rng: np.random.Generator, height: int, width: int, scale_min: float,
               scale_max: float) -> np.ndarray:
        """A random crop as float32 (3, height, width) in [-1, 1]."""
        i = int(rng.integers(0, len(self.files)))
        return to_network(random_resized_crop(load_rgb(self.files[i]), height, width, scale_min, scale_max, rng,
                                              self.valid_area(i)))


SEQUENCES = "sequences"
"""Sub-folder of a real folder that holds sequences: ``REAL/sequences/NAME/images/*.png|jpg``,
consecutive frames in file-name order (the stand-in real domain writes this layout). When the
real folder given is an ``images`` folder (``REAL/images``, as the stand-in's single frames), its
sibling ``REAL/sequences`` is used."""


def sequences_root(folder: str | os.PathLike) -> Path:
    """Where the sequences of real folder ``folder`` are (see :data:`SEQUENCES`)."""
    folder = Path(folder)
    if not (folder / SEQUENCES).is_dir() and folder.name == "images" and (folder.parent / SEQUENCES).is_dir():
        return folder.parent / SEQUENCES
    return folder / SEQUENCES


class RealSequences:
    """Consecutive real frames for the video methods: every ``sequences/*/images`` folder (see
    :func:`sequences_root`) with at least ``length`` frames is a sequence (docs/formats.md)."""

    def __init__(self, folder: str | os.PathLike, length: int = 3):
        self.folder = Path(folder)
        root = sequences_root(self.folder)
        self.sequences = []
        if root.is_dir():
            for d in sorted(p for p in root.iterdir() if (p / "images").is_dir()):
                files = sorted(f for f in (d / "images").iterdir() if f.suffix.lower() in EXTENSIONS and f.is_file())
                if len(files) >= length:
                    self.sequences.append(files)
        if not self.sequences:
            raise UserError(f"the real folder {self.folder} has no sequences of {length} or more frames "
                            f"({self.folder}/{SEQUENCES}/NAME/images/*.png, consecutive frames in name order); "
                            "video methods train on consecutive real frames")
        self.length = length

    def sample(self, rng: np.random.Generator, height: int, width: int, scale_min: float,
               scale_max: float) -> list[np.ndarray]:
        """``length`` consecutive frames of a random sequence, one random resized crop for all, as
        float32 (3, height, width) in [-1, 1]."""
        files = self.sequences[int(rng.integers(0, len(self.sequences)))]
        start = int(rng.integers(0, len(files) - self.length + 1))
        frames = [load_rgb(f) for f in files[start : start + self.length]]
        return [to_network(c) for c in random_resized_crops(frames, height, width, scale_min, scale_max, rng)]
