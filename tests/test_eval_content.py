"""The evaluation reads a real set's frames through their content masks: the black surround of a
circular endoscope view never reaches the realism measures."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from sim2real.cli.main import main
from sim2real.data.cover import fit_image, resize_box
from sim2real.data.real import load_rgb
from sim2real.errors import UserError
from sim2real.inference.realimages import ContentWindows, RealSet, find_real
from sim2real.metrics.twosample import c2st

SH, SW = 96, 128  # source frames
EH, EW = 32, 64  # the evaluation's size


def tissue(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Smooth coloured 'tissue' (a 4x6 grid of random colours, bicubic), never near black."""
    coarse = rng.integers(70, 230, (4, 6, 3)).astype(np.float32)
    return np.clip(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC), 60, 240).astype(np.uint8)


def view(img: np.ndarray) -> np.ndarray:
    """A circular endoscope view (black surround) with a static on-screen bar inside it."""
    yy, xx = np.mgrid[:SH, :SW]
    img = img.copy()
    img[(yy + 0.5 - SH / 2) ** 2 + (xx + 0.5 - SW / 2) ** 2 > 44 ** 2] = 0
    img[58:66, 40:88] = 20
    img[60:64, 44:84:6] = 250  # its 'text'
    return img


@pytest.fixture(scope="module")
def realset(tmp_path_factory):
    """A real set of 48 frames of two sources seen through :func:`view`, and 48 frames of the same
    tissue without view or bar, taken through the same crop and resizing (a perfect generator's)."""
    root = tmp_path_factory.mktemp("footage")
    rng = np.random.default_rng(0)
    for src in ("a", "b"):
        (root / "src" / src).mkdir(parents=True)
        for i in range(24):
            Image.fromarray(view(tissue(rng, SH, SW))).save(root / "src" / src / f"{i:03d}.png")
    assert main(["realset", str(root / "src"), "--out", str(root / "real"), "--format", "png", "--height", "64",
                 "--dup-distance", "-1", "--held-out", "0", "--quiet"]) == 0
    m = json.loads((root / "real" / "manifest.json").read_text())
    top, left, bottom, right = m["sources"][0]["box"]
    h, w = m["frames"][0]["size"]
    mask = root / "real" / m["sources"][0]["mask"]
    box = ContentWindows().box(mask, (h, w), EH, EW)
    gen = []
    for _ in range(48):
        stored = cv2.resize(tissue(rng, SH, SW)[top:bottom, left:right], (w, h), interpolation=cv2.INTER_AREA)
        gen.append(resize_box(stored, box, EH, EW))
    return root / "real", gen


def test_real_frames_are_cut_inside_the_content_mask(realset):
    rs = find_real(realset[0])
    assert len(rs.images) == 48 and all(m is not None and m.is_file() for m in rs.masks)
    whole = [fit_image(load_rgb(p), EH, EW) for p in rs.images]
    cut = rs.frames(rs.images, EH, EW)
    assert all(f.shape == (EH, EW, 3) for f in cut)
    # tissue is never below 60 nor above 240: a surround or bar pixel, even blended by the filter, shows
    assert min(int(f.min()) for f in cut) >= 55 and max(int(f.max()) for f in cut) <= 245
    # the centre window of the whole frame (the old reading) holds the circle's black corners and the
    # bar: the bar's 8 of 88 rows over 48 of 88 columns alone are 5 % of the box, 10 % of its middle half
    dark = np.mean([(f.max(2) < 25).mean() for f in whole])
    assert dark > 0.05, dark


def test_c2st_sees_tissue_not_the_surround(realset):
    """Generated frames of the same tissue without any border: the classifier test cannot tell
    them from the masked real frames (AUC near 0.5), nor real frames from real ones, while the
    real frames read whole (surround and bar) are told apart from them."""
    rs, gen = find_real(realset[0]), realset[1]
    cut = rs.frames(rs.images, EH, EW)
    whole = [fit_image(load_rgb(p), EH, EW) for p in rs.images]
    kw = dict(seed=0, steps=100, crop=24)
    real_vs_real = c2st(cut[::2], cut[1::2], **kw)["auc"]
    gen_vs_cut = c2st(gen, cut, **kw)["auc"]
    gen_vs_whole = c2st(gen, whole, **kw)["auc"]
    assert abs(real_vs_real - 0.5) < 0.25, real_vs_real
    assert abs(gen_vs_cut - 0.5) < 0.25, gen_vs_cut
    assert gen_vs_whole < 0.1 or gen_vs_whole > 0.9, gen_vs_whole  # separable (either side of 0.5)


def test_a_mask_of_another_size_is_one_error_line(realset, tmp_path):
    rs = find_real(realset[0])
    Image.fromarray(np.full((10, 10), 255, np.uint8)).save(tmp_path / "small.png")
    bad = RealSet(rs.root, rs.label_root, rs.images[:1], rs.labels[:1], [tmp_path / "small.png"])
    with pytest.raises(UserError, match="content mask .* is 10x10 but its image is"):
        bad.frames(bad.images, EH, EW)


def test_plain_folder_frames_are_used_whole(tmp_path):
    img = np.zeros((40, 80, 3), np.uint8)
    img[:, :, 1] = np.arange(80, dtype=np.uint8)[None, :] * 3
    Image.fromarray(img).save(tmp_path / "x.png")
    rs = find_real(tmp_path)
    assert rs.masks == [] and rs.label_classes is None
    assert np.array_equal(rs.frames(rs.images, 20, 40)[0], fit_image(img, 20, 40))


def test_manifest_without_label_classes_reads_as_the_paper_five(realset):
    m = json.loads((realset[0] / "manifest.json").read_text())
    assert m["label_classes"] is None and find_real(realset[0]).label_classes is None
