"""``realset --calibration``: footage seen through a barrel-distorting lens is undistorted before
anything else (frames and labels), and each source reports its stored frames' pinhole intrinsics.

The frames are made here: a pinhole picture (smooth texture, a straight vertical label boundary)
is bent by OpenCV's distortion model with known coefficients; undistorting with them must give the
pinhole picture back."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from sim2real.cli.main import main
from sim2real.footage.undistort import Calibration, Undistorter, read_calibration, stored_intrinsics

H, W = 240, 320
FX, FY, CX, CY = 200.0, 205.0, 161.0, 118.5  # OpenCV's convention: pixel centres at integers
DIST = [-0.3, 0.08, 0.0, 0.0, 0.0]
BOUNDARY = 100  # the label boundary: column 100 of the pinhole picture


def pinhole_picture() -> tuple[np.ndarray, np.ndarray]:
    """A smooth random texture and labels 21 left of column BOUNDARY, 50 right of it."""
    rng = np.random.default_rng(3)
    small = rng.uniform(60, 220, (H // 10, W // 10, 3)).astype(np.uint8)
    img = cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)
    lab = np.full((H, W), 50, np.uint8)
    lab[:, :BOUNDARY] = 21
    return img, lab


def distort(pinhole: np.ndarray, interpolation: int) -> np.ndarray:
    """What the lens shows: distorted pixel d looks at the pinhole position undistort(d)."""
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    grid = np.stack(np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64)), -1)
    und = cv2.undistortPoints(grid.reshape(-1, 1, 2), K, np.array(DIST), P=K).reshape(H, W, 2).astype(np.float32)
    return cv2.remap(pinhole, und[..., 0], und[..., 1], interpolation, borderMode=cv2.BORDER_REFLECT)


def calibration_file(tmp_path, **changes):
    data = {"width": W * 2, "height": H * 2, "fx": FX * 2, "fy": FY * 2, "cx": CX * 2 + 0.5, "cy": CY * 2 + 0.5,
            "dist": DIST, **changes}  # calibrated at twice the frames' size: the matrix scales
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(data))
    return path


def test_undistorting_gives_the_pinhole_picture_back(tmp_path):
    img, lab = pinhole_picture()
    bent, bent_lab = distort(img, cv2.INTER_LINEAR), distort(lab, cv2.INTER_NEAREST)
    und = Undistorter(read_calibration(calibration_file(tmp_path)))
    np.testing.assert_allclose(und.calibration.at(H, W), [[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    inner = (slice(20, H - 20), slice(20, W - 20))
    err = np.abs(und(bent).astype(float) - img)[inner].mean()
    assert err < 3.0 and np.abs(bent.astype(float) - img)[inner].mean() > 4 * err
    # the label boundary is straight again: column BOUNDARY on every row (within a pixel)
    back = und(bent_lab, labels=True)
    for row in range(20, H - 20, 10):
        assert abs(int(np.argmax(back[row] != 21)) - BOUNDARY) <= 1, row
    assert max(abs(int(np.argmax(bent_lab[r] != 21)) - BOUNDARY) for r in (20, H // 2, H - 20)) >= 4


def test_stored_intrinsics_follow_the_crop_and_the_resize():
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    # crop rows 10..230 and columns 40..280 (220 x 240), stored at 110 x 120: half the size
    fx, fy, cx, cy = stored_intrinsics(K, (10, 40, 230, 280), (110, 120))
    assert (fx, fy) == (FX / 2, FY / 2)
    assert (cx, cy) == ((CX + 0.5 - 40) / 2, (CY + 0.5 - 10) / 2)  # pixel centre convention shifted by 0.5


def test_realset_undistorts_frames_and_labels_and_reports_the_intrinsics(tmp_path, capsys):
    img, lab = pinhole_picture()
    src, labels = tmp_path / "frames", tmp_path / "labels"
    src.mkdir(), labels.mkdir()
    for k in range(2):
        Image.fromarray(distort(np.roll(img, 30 * k, axis=0), cv2.INTER_LINEAR)).save(src / f"{k:03d}.png")
        Image.fromarray(distort(lab, cv2.INTER_NEAREST)).save(labels / f"{k:03d}.png")
    (tmp_path / "map.json").write_text(json.dumps({"21": "liver", "50": "fat"}))
    code = main(["realset", str(src), "--out", str(tmp_path / "real"), "--calibration", str(calibration_file(tmp_path)),
                 "--labels", str(labels), "--label-map", str(tmp_path / "map.json"), "--format", "png",
                 "--dup-distance", "-1", "--held-out", "0", "--height", str(H // 2), "--quiet"])
    io = capsys.readouterr()
    assert code == 0, io.err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    assert m["settings"]["calibration"] == str(calibration_file(tmp_path))
    src_row = m["sources"][0]
    assert src_row["box"] == [0, 0, H, W]  # barrel distortion undistorted with its own K leaves no border
    np.testing.assert_allclose(src_row["intrinsics"], [FX / 2, FY / 2, (CX + 0.5) / 2, (CY + 0.5) / 2])
    assert "undistorted; the stored frames' pinhole intrinsics: fx 100.0, fy 102.5, cx 80.8, cy 59.5 px" in io.out
    stored = np.asarray(Image.open(tmp_path / "real" / m["frames"][0]["file"]).convert("RGB")).astype(float)
    half = cv2.resize(img, (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    assert np.abs(stored - half)[10:-10, 10:-10].mean() < 3.0
    stored_lab = np.asarray(Image.open(tmp_path / "real" / m["frames"][0]["label"]))
    for row in range(10, H // 2 - 10, 10):  # liver (label 0) up to column 50 of the half-size frame
        assert abs(int(np.argmax(stored_lab[row] != 0)) - BOUNDARY // 2) <= 1, row


@pytest.mark.parametrize("changes,words", [
    ({"dist": [0.1, 0.2, 0.3]}, "dist holds 4, 5 or 8 coefficients"),
    ({"fx": -1}, "positive focal lengths"),
    ({"cx": 5000}, "principal point inside"),
    ({"fy": "wide"}, "numbers"),
    ({"width": 100, "height": 100}, "do not have the aspect"),
])
def test_a_bad_calibration_is_one_line_and_nothing_is_written(tmp_path, capsys, changes, words):
    img, _ = pinhole_picture()
    (tmp_path / "frames").mkdir()
    Image.fromarray(img).save(tmp_path / "frames" / "000.png")
    if "width" in changes:
        changes = {**changes, "cx": 50, "cy": 50}
    code = main(["realset", str(tmp_path / "frames"), "--out", str(tmp_path / "real"),
                 "--calibration", str(calibration_file(tmp_path, **changes)), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and words in err, err
    assert not (tmp_path / "real").exists()


def test_calibration_scales_with_the_frame_size():
    cal = Calibration(640, 480, np.array([[400.0, 0, 319.5], [0, 400.0, 239.5], [0, 0, 1]]), np.zeros(5))
    # pixel centres at integers: centre u of the 640 px image lies at (u + 0.5) / 2 - 0.5 at 320 px
    np.testing.assert_allclose(cal.at(240, 320), [[200, 0, 159.5], [0, 200, 119.5], [0, 0, 1]])


def test_the_fov_note_gives_the_crops_range_and_the_value_to_set():
    from sim2real.data.real import field_of_view_note

    # 60 degrees at scale 1: 2 atan(tan 30 / 1.2) = 51.38 at scale 1.2; 2 atan(tan 30 / sqrt 1.2) = 55.58
    note = field_of_view_note([58.0, 60.0, 62.0], 75.0, 1.0, 1.2)
    assert note.startswith("note: the real set's calibrated training crops see 51.4-60.0 degrees across, "
                           "the simulated views 75.0") and "set data.fov_x_deg=55.6" in note
    assert field_of_view_note([60.0], 56.0, 1.0, 1.2) is None  # within 10 % of 55.58
    assert field_of_view_note([], 75.0, 1.0, 1.2) is None  # nothing calibrated


def test_training_on_a_calibrated_set_notes_another_field_of_view(tmp_path, capsys, train_inputs):
    from sim2real.data.real import RealImages

    img, _ = pinhole_picture()
    (tmp_path / "frames").mkdir()
    for k in range(3):
        Image.fromarray(distort(np.roll(img, 30 * k, axis=0), cv2.INTER_LINEAR)).save(tmp_path / "frames" / f"{k}.png")
    assert main(["realset", str(tmp_path / "frames"), "--out", str(tmp_path / "real"), "--calibration",
                 str(calibration_file(tmp_path)), "--dup-distance", "-1", "--held-out", "0", "--quiet"]) == 0
    capsys.readouterr()
    # 240x320 frames, fx 200: the largest 1:2 window is at most 320 px wide, at least 300 (the
    # resampling filter's margin): 2 atan(150 / 200) = 73.7 to 2 atan(160 / 200) = 77.3 degrees
    fovs = RealImages(tmp_path / "real").crop_fields_of_view(64, 128)
    assert len(fovs) == 3 and all(73.7 <= f <= 77.3 for f in fovs), fovs
    code = main(["train", "--preset", "tiny", "--scenes", str(train_inputs[0]), "--real", str(tmp_path / "real"),
                 "--out", str(tmp_path / "run"), "--iterations", "1", "--device", "cpu", "--no-progress",
                 "--set", "data.fov_x_deg=40", "data.workers=0"])
    io = capsys.readouterr()
    assert code == 0, io.err
    assert "note: the real set's calibrated training crops see " in io.out and "simulated views 40.0" in io.out


def test_a_frame_whose_view_moved_gets_its_own_principal_point(tmp_path, capsys):
    """Without distortion (dist 0) undistorting keeps the frames. The scope's circle (radius 50)
    sits at x = 100 in frames 0-3 and at x = 135 in frames 4-5: each frame gets its own box
    (columns 50..150, then 85..185), stored at about scale 1 (100 px high), and with it its own
    principal point: the calibration's x = 100 lies about 50 px, then about 15 px, inside it."""
    from sim2real.data.real import RealImages
    from tests.test_footage import circle_frame, save

    src = tmp_path / "frames"
    for i in range(6):
        save(src / f"{i:03d}.png", circle_frame(i, cx=100 if i < 4 else 135))
    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps({"width": 200, "height": 120, "fx": 90.0, "fy": 90.0, "cx": 99.5, "cy": 59.5,
                                 "dist": [0, 0, 0, 0]}))
    code = main(["realset", str(src), "--out", str(tmp_path / "real"), "--calibration", str(calib),
                 "--format", "png", "--dup-distance", "-1", "--height", "100", "--quiet"])
    assert code == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    cx = {f["index"]: f["intrinsics"][2] for f in m["frames"]}
    assert sorted(cx) == list(range(6))
    assert all(46 <= cx[i] <= 54 for i in range(4)) and all(11 <= cx[i] <= 19 for i in (4, 5)), cx
    assert all(f["intrinsics"][0] == pytest.approx(90.0, rel=0.06) for f in m["frames"])
    real = RealImages(tmp_path / "real")  # training reads each frame's own
    assert [K[2] for K in real.intrinsics] == [cx[int(p.stem)] for p in real.files]
