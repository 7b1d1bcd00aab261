"""The training's real-image pool: crops inside a real set's content mask, the index of a plain
folder kept in the run folder, and the one cover-resize."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from sim2real.cli.main import main
from sim2real.data.cover import ValidArea, fit_image, random_cover_crops
from sim2real.data.real import INDEX, RealImages, enlargement_note
from sim2real.errors import UserError

H, W = 120, 200


def reddish(seed: int) -> np.ndarray:
    """Content whose red channel is always 150 or more, so that any masked (black) pixel blended
    into a crop shows as red below 150."""
    rng = np.random.default_rng(seed)
    img = np.empty((H, W, 3), np.uint8)
    img[..., 0] = rng.integers(150, 256, (H, W))
    img[..., 1:] = rng.integers(40, 120, (H, W, 2))
    return img


def test_crops_from_a_masked_real_set_never_hold_masked_pixels(tmp_path, capsys):
    yy, xx = np.mgrid[:H, :W]
    for i in range(4):
        img = reddish(i)
        img[(yy + 0.5 - 60) ** 2 + (xx + 0.5 - 100) ** 2 > 55 ** 2] = 0  # circular view, black surround
        img[100:112, 60:140] = (20, 20, 20)  # and a static dark bar inside it
        Image.fromarray(img).save(tmp_path / f"f{i}.png")
    assert main(["realset", str(tmp_path), "--out", str(tmp_path / "real"), "--format", "png",
                 "--dup-distance", "-1", "--quiet"]) == 0
    capsys.readouterr()
    pool = RealImages(tmp_path / "real")
    assert pool.realset and len(pool) == 4
    assert pool.sizes == [Image.open(f).size[::-1] for f in pool.files]  # read from the manifest
    mask = pool.valid_area(0).mask
    assert not mask.all() and mask.mean() > 0.4  # the set is masked (surround and bar)
    rng = np.random.default_rng(0)
    for _ in range(60):
        crop = pool.sample(rng, 32, 64, 1.0, 1.3)
        red = (crop[0] + 1) * 127.5
        assert red.min() >= 149.5
    # without the mask the same frames give crops with surround in them
    plain = RealImages(tmp_path / "real" / "images")
    reds = [((plain.sample(rng, 32, 64, 1.0, 1.3)[0] + 1) * 127.5).min() for _ in range(20)]
    assert min(reds) < 100


def test_valid_area_window_fits_and_varies():
    mask = np.zeros((100, 100), bool)
    mask[20:80, 10:90] = True  # a 60 x 80 content rectangle
    va = ValidArea(mask)
    k = va.inscribed_scale(10, 20)  # 2:1 windows: at most 80 wide (less the filter's reach)
    assert 3.5 < k < 4.0
    rng = np.random.default_rng(1)
    boxes = [va.draw(10, 20, 1.5, rng) for _ in range(30)]
    for l, t, r, b in boxes:
        assert 10 <= l - 1 and r + 1 <= 90 and 20 <= t - 1 and b + 1 <= 80
        assert (r - l) / (b - t) == pytest.approx(2.0)
    assert len({(round(l), round(t)) for l, t, _, _ in boxes}) > 5


def test_plain_folder_is_indexed_once_into_the_run_folder(tmp_path):
    real, run = tmp_path / "real", tmp_path / "run"
    real.mkdir()
    run.mkdir()
    for i in range(3):
        Image.fromarray(reddish(i)).save(real / f"{i}.png")
    pool = RealImages(real, index=run / INDEX)
    pool.save_index()
    idx = json.loads((run / INDEX).read_text())
    assert idx["files"] == ["0.png", "1.png", "2.png"]
    # an image damaged afterwards is not checked again on the next start (the index is used) ...
    (real / "1.png").write_bytes(b"damaged")
    again = RealImages(real, index=run / INDEX)
    assert [p.name for p in again.files] == ["0.png", "1.png", "2.png"]
    # ... but a folder that changed (an image added) is listed and checked anew
    Image.fromarray(reddish(9)).save(real / "3.png")
    with pytest.raises(UserError, match="1.png"):
        RealImages(real, index=run / INDEX)


def test_frames_smaller_than_the_crop_are_named(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    Image.new("RGB", (854, 480)).save(real / "a.png")
    Image.new("L", (300, 100)).save(real / "b.png")
    pool = RealImages(real)
    assert pool.sizes == [(480, 854), (100, 300)]
    # 256x512 crops: a.png scaled by max(256/480, 512/854) = 0.6, b.png by max(2.56, 1.71) = 2.56
    assert pool.enlargements(256, 512) == pytest.approx([0.6, 2.56], abs=1e-3)
    note = enlargement_note(pool.enlargements(256, 512), 256, 512)
    assert note.startswith("note: 1 of 2 real frames hold less than the 256x512 training crop and are enlarged (up to 2.6x)")
    assert enlargement_note(pool.enlargements(108, 176), 108, 176) is None  # b.png: max(1.08, 0.587) < 1.1
    assert "up to 1.1x" in enlargement_note(pool.enlargements(112, 176), 112, 176)  # b.png: 1.12
    assert RealImages(real, verify=False).enlargements(256, 512) is None  # sizes unknown


def test_a_circular_view_holds_less_than_its_box(tmp_path, capsys):
    # frames of a circular view of radius 80 px in a black surround; the real set keeps the
    # circle's box (a little less: the rim is eroded). The largest 1:2 window inside a circle of
    # diameter d has its half-diagonal on the circle, (h/2)^2 + h^2 = (d/2)^2, so h = d/sqrt(5),
    # and a crop of height H is enlarged by H*sqrt(5)/d, a little more for the filter's reach
    yy, xx = np.mgrid[:200, :240]
    for i in range(3):
        img = np.random.default_rng(i).integers(90, 250, (200, 240, 3), dtype=np.uint8)
        img[(yy + 0.5 - 100) ** 2 + (xx + 0.5 - 120) ** 2 > 80 ** 2] = 0
        Image.fromarray(img).save(tmp_path / f"f{i}.png")
    assert main(["realset", str(tmp_path), "--out", str(tmp_path / "real"), "--format", "png",
                 "--dup-distance", "-1", "--quiet"]) == 0
    capsys.readouterr()
    pool = RealImages(tmp_path / "real")
    d = max(max(h, w) for h, w in pool.sizes)
    assert 150 <= d <= 160  # the circle's box, not the 200 x 240 frame
    small, large = pool.enlargements(64, 128), pool.enlargements(96, 192)
    for f, height in ((small, 64), (large, 96)):
        assert all(1.0 <= x / (height * 5 ** 0.5 / d) < 1.05 for x in f), (f, d)
    assert enlargement_note(small, 64, 128) is None  # about 0.94
    # about 1.39, where the box alone would have said max(96 / d, 192 / d) = 1.22
    assert enlargement_note(large, 96, 192).startswith("note: 3 of 3 real frames hold less than the 96x192")


def test_cover_resize_equals_resizing_the_whole_image():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (90, 170, 3), dtype=np.uint8)
    # reference: resize the whole image to cover 40 x 100 (factor 100 / 170), crop the centre
    nw, nh = 100, round(90 * 100 / 170)
    whole = np.asarray(Image.fromarray(img).resize((nw, nh), Image.BILINEAR))
    top = (nh - 40) // 2
    ref = whole[top:top + 40]
    out = fit_image(img, 40, 100)
    assert out.shape == (40, 100, 3) and np.abs(out.astype(int) - ref).max() <= 2
    # random crops at factor 1 with a full-width target see the full width
    half = np.zeros((100, 100, 3), np.uint8)
    half[:, 50:] = 255
    crop = random_cover_crops([half], 32, 64, 1.0, 1.0, rng)[0]
    assert crop[:, :20].max() < 10 and crop[:, -20:].min() > 245
