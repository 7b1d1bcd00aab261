"""Specular highlights (footage/highlights.py, ``realset --highlights inpaint``): small white spots
brighter than their surroundings are found and painted out in the surrounding colour; a large
uniformly pale organ and the black surround are left alone."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from sim2real.cli.main import main
from sim2real.footage.highlights import highlight_mask, inpaint_highlights

H, W = 256, 384
TISSUE = (150, 40, 40)  # dark red: HSV value 150, saturation 187
PALE = (235, 225, 190)  # a pale yellow organ: value 235, saturation 49, a disc with a soft rim
ORGAN_R = 60
SPOTS = [(60, 60), (200, 90), (128, 300)]  # centres (row, column) of the white spots
SPOT_R = 3


def frame() -> tuple[np.ndarray, np.ndarray]:
    """A 256x384 frame of red tissue (+-6 levels of noise) with three white spots of radius 3 and a
    pale organ (a disc of radius 60 around (160, 210), its rim blurred by 6 px), and the full frame
    as its content."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:H, :W]
    organ = cv2.GaussianBlur((np.hypot(yy - 160, xx - 210) <= ORGAN_R).astype(np.float32), (0, 0), 6)[..., None]
    img = (np.array(TISSUE, np.float32) * (1 - organ) + np.array(PALE, np.float32) * organ
           + rng.uniform(-6, 6, (H, W, 1))).clip(0, 255).astype(np.uint8)
    for r, c in SPOTS:
        img[np.hypot(yy - r, xx - c) <= SPOT_R] = 255
    return img, np.ones((H, W), bool)


def test_white_spots_are_found_and_a_pale_organ_is_not():
    img, content = frame()
    mask = highlight_mask(img, content)
    yy, xx = np.mgrid[:H, :W]
    near = np.zeros((H, W), bool)
    for r, c in SPOTS:
        d = np.hypot(yy - r, xx - c)
        assert mask[d <= SPOT_R].all()  # every spot pixel
        near |= d <= SPOT_R + 256 / 128 + 1.5  # grown by short side / 128 = 2 px (+ the square kernel's corner)
    assert not (mask & ~near).any()  # nothing else: not the pale square, not the noisy tissue
    assert not mask[np.hypot(yy - 160, xx - 210) <= ORGAN_R + 20].any()


def test_spots_are_painted_in_the_surrounding_colour_and_the_rest_is_untouched():
    img, content = frame()
    out, share = inpaint_highlights(img, content)
    mask = highlight_mask(img, content)
    assert share == mask.sum() / (H * W)
    # 3 discs of radius 3 grown by 2 px: about 3 * pi * 5^2 pixels
    assert 0.6 * 3 * np.pi * 25 <= mask.sum() <= 1.6 * 3 * np.pi * 25
    for r, c in SPOTS:
        np.testing.assert_allclose(out[r, c], TISSUE, atol=12)
    assert np.array_equal(out[~mask], img[~mask])


def test_the_content_mask_bounds_the_search():
    img, _ = frame()
    content = np.zeros((H, W), bool)
    content[:, 192:] = True  # only the right half is the view: the spots at columns 60 and 90 lie outside
    mask = highlight_mask(img, content)
    assert mask[128, 300] and not mask[:, :192].any()
    out, share = inpaint_highlights(img, np.zeros((H, W), bool))
    assert share == 0.0 and out is img


def test_realset_paints_out_highlights_on_request(tmp_path, capsys):
    img, _ = frame()
    src = tmp_path / "frames"
    src.mkdir()
    for k in range(2):
        Image.fromarray(np.roll(img, 40 * k, axis=1)).save(src / f"{k:03d}.png")
    out = tmp_path / "real"
    code = main(["realset", str(src), "--out", str(out), "--highlights", "inpaint", "--format", "png",
                 "--dup-distance", "-1", "--held-out", "0", "--quiet"])
    io = capsys.readouterr()
    assert code == 0, io.err
    m = json.loads((out / "manifest.json").read_text())
    assert m["settings"]["highlights"] == "inpaint"
    shares = [f["highlights"] for f in m["frames"]]
    assert len(shares) == 2 and all(0.6 * 3 * np.pi * 25 / (H * W) < s < 0.01 for s in shares)
    assert "highlights painted out: median " in io.out
    stored = np.asarray(Image.open(out / m["frames"][0]["file"]).convert("RGB"))
    assert (stored.min(axis=2) > 240).sum() == 0  # no white pixel left
    with pytest.raises(SystemExit) as exit_:
        main(["realset", str(src), "--out", str(tmp_path / "bad"), "--highlights", "remove"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and "invalid choice: 'remove'" in err
    assert not (tmp_path / "bad").exists()


def test_a_large_white_region_is_left_and_the_spots_beside_it_are_not():
    """A clipped white bar of 30 x 200 px (an overexposed instrument shaft: 6 % of the content,
    above the 2 % limit) stays as it is; the three spots are still painted out."""
    img, content = frame()
    img[200:230, 150:350] = 255
    mask = highlight_mask(img, content)
    assert not mask[195:235, 145:355].any()
    assert all(mask[r, c] for r, c in SPOTS)
    out, _ = inpaint_highlights(img, content)
    assert (out[200:230, 150:350] == 255).all()
    # a bar of 10 x 40 px (0.4 % of the content) is small enough: it is found and painted out
    img, _ = frame()
    img[200:210, 150:190] = 255
    assert highlight_mask(img, content)[200:210, 150:190].all()
