"""sim2real realset: content area, sampling, filters, split, labels and bad input, on small
synthetic frames and videos made here."""

from __future__ import annotations

import json
import re
from pathlib import Path

import av
import numpy as np
import pytest
from conftest import private_outputs
from PIL import Image, ImageDraw

from sim2real.cli.main import main
from sim2real.footage import content

H, W = 120, 200


def texture(seed: int, h: int = H, w: int = W) -> np.ndarray:
    """A smooth random tissue-like RGB texture (blurred noise, values 60..230)."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(60, 230, (h // 8 + 1, w // 8 + 1, 3)).astype(np.uint8)
    return np.asarray(Image.fromarray(small).resize((w, h), Image.BICUBIC)).clip(60, 230).astype(np.uint8)


def circle_frame(seed: int, cy=60, cx=100, r=50) -> np.ndarray:
    yy, xx = np.mgrid[:H, :W]
    img = texture(seed)
    img[(yy + 0.5 - cy) ** 2 + (xx + 0.5 - cx) ** 2 > r * r] = 0
    return img


def save(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)
    return path


def stats_of(frames) -> content.FrameStats:
    st = content.FrameStats()
    for f in frames:
        st.add(f)
    return st


def run_cli(args, capsys):
    code = main(args)
    return code, capsys.readouterr()


def test_circular_view_is_masked_and_cropped_to_its_box():
    area = content.detect(stats_of([circle_frame(s) for s in range(4)]))
    t, l, b, r = area.box
    # the circle of radius 50 around (60, 100): rows 10..110, columns 50..150
    assert abs(t - 10) <= 3 and abs(b - 110) <= 3 and abs(l - 50) <= 3 and abs(r - 150) <= 3
    assert area.shape == "circle"
    yy, xx = np.mgrid[:H, :W]
    d = np.hypot(yy + 0.5 - 60, xx + 0.5 - 100)
    assert not area.mask[d > 50].any()          # nothing of the surround is content
    assert area.mask[d < 46].mean() > 0.99       # the view is, up to its soft rim


def test_single_frame_circle_and_dark_tissue_inside():
    img = circle_frame(0)
    img[50:70, 90:110] = 5  # dark tissue inside the view stays content (convex hull)
    area = content.detect(stats_of([img]))
    assert area.mask[55:65, 95:105].all()


def test_a_frame_whose_view_moved_gets_its_own_mask_and_box(tmp_path, capsys):
    src = tmp_path / "frames"
    for i in range(6):  # the scope moves after frame 3: the circle's centre goes from x=100 to x=135
        save(src / f"{i:03d}.png", circle_frame(i, cx=100 if i < 4 else 135))
    code, io = run_cli(["realset", str(src), "--out", str(tmp_path / "real"), "--format", "png",
                        "--dup-distance", "-1", "--quiet"], capsys)
    assert code == 0, io.err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    assert len(m["frames"]) == 6
    for f in m["frames"]:
        mask = np.asarray(Image.open(tmp_path / "real" / "masks" / f"{f['mask']}.png")) > 127
        img = np.asarray(Image.open(tmp_path / "real" / f["file"]))
        # each stored frame is its own circle's box (100 px, within a few) and has no surround inside its mask
        assert abs(img.shape[0] - 100) <= 4 and abs(img.shape[1] - 100) <= 4, (f["index"], img.shape)
        assert mask.shape == img.shape[:2] and img[mask].max(axis=1).min() >= 60 * 0.9
    # the summary names the largest 1:2 crop inside the circle: a window with its half-diagonal on
    # a circle of diameter d = 100 (within a few) is d/sqrt(5) = 44.7 high, less the filter's reach
    sizes = [tuple(map(int, x)) for x in re.findall(r"1:2 crops up to (\d+)x(\d+) px unenlarged", io.out)]
    assert sizes and all(38 <= h <= 47 and w in (2 * h, 2 * h + 1) for h, w in sizes), io.out


def _bar_frames(n: int, top: int) -> list[np.ndarray]:
    frames = []
    for s in range(n):
        img = Image.fromarray(texture(100 + s))
        d = ImageDraw.Draw(img)
        d.rectangle([20, top, 180, top + 12], fill=(50, 50, 50))
        d.text((24, top + 1), "OSD 12:34 ZOOM", fill=(255, 255, 255))
        frames.append(np.asarray(img))
    return frames


@pytest.mark.parametrize("top", [50, 106])
def test_static_text_bar_is_masked(top):
    area = content.detect(stats_of(_bar_frames(8, top)))
    bar = np.zeros((H, W), bool)
    bar[top:top + 13, 20:181] = True
    assert not area.mask[bar].any()
    # far from the bar (beyond the dilation of 1 % of the short side plus a pixel) all is content
    far = np.ones((H, W), bool)
    far[max(0, top - 6):top + 19, 12:189] = False
    assert area.mask[far].mean() > 0.97


def test_still_scene_is_not_an_overlay():
    frames = [texture(7)] * 5  # nothing moves: no overlay can be told from the scene
    area = content.detect(stats_of(frames))
    assert area.overlay_fraction == 0 and area.mask.all()


def _video(path: Path, seconds: float = 3, fps: int = 25, size=(64, 96)) -> Path:
    with av.open(str(path), "w") as c:
        st = c.add_stream("mpeg4", rate=fps)
        st.width, st.height, st.pix_fmt = size[1], size[0], "yuv420p"
        for i in range(round(seconds * fps)):
            frame = av.VideoFrame.from_ndarray(texture(i, *size), format="rgb24")
            for p in st.encode(frame):
                c.mux(p)
        for p in st.encode():
            c.mux(p)
    return path


def test_video_at_5_fps_gives_15_frames_of_3_seconds(tmp_path, capsys):
    video = _video(tmp_path / "clip.mp4")
    code, io = run_cli(["realset", str(video), "--out", str(tmp_path / "real"), "--dup-distance", "-1", "--quiet"],
                       capsys)
    assert code == 0, io.err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    times = [f["time"] for f in m["frames"]]
    assert len(times) == 15 and times == pytest.approx([i * 0.2 for i in range(15)], abs=0.021)
    assert all(Path(tmp_path / "real" / f["file"]).is_file() for f in m["frames"])
    assert private_outputs(tmp_path / "real", tmp_path) == []
    # a time range and --max-frames: 1.0 s .. 2.0 s at 5 fps is 5 frames, capped at 3
    code, io = run_cli(["realset", f"{video}@1-2", "--out", str(tmp_path / "r2"), "--dup-distance", "-1",
                        "--max-frames", "3", "--quiet"], capsys)
    m = json.loads((tmp_path / "r2" / "manifest.json").read_text())
    assert code == 0 and [f["time"] for f in m["frames"]] == pytest.approx([1.0, 1.2, 1.4], abs=0.021)


def test_duplicates_and_black_frames_are_dropped_and_counted(tmp_path, capsys):
    src = tmp_path / "frames"
    for i in range(4):
        save(src / f"f{i:03d}.png", texture(i))
    for i in range(4, 7):
        save(src / f"f{i:03d}.png", texture(1))               # copies of frame 1
    for i in range(7, 9):
        save(src / f"f{i:03d}.png", np.full((H, W, 3), 3, np.uint8))    # lens covered
    save(src / "f009.png", np.full((H, W, 3), 254, np.uint8))           # white-out
    code, io = run_cli(["realset", str(src), "--out", str(tmp_path / "real"), "--quiet"], capsys)
    assert code == 0, io.err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    assert m["kept"] == 4 and m["dropped"] == {"dark": 2, "overexposed": 1, "duplicate": 3, "small_content": 0}
    assert "kept 4 frames" in io.out and "duplicate 3" in io.out and "dark 2" in io.out


def test_held_out_never_shares_a_source_with_train(tmp_path, capsys):
    for s in range(5):
        for i in range(3):
            save(tmp_path / "src" / f"case{s}" / f"{i:04d}.png", texture(10 * s + i))
    code, io = run_cli(["realset", str(tmp_path / "src"), "--out", str(tmp_path / "real"), "--quiet"], capsys)
    assert code == 0, io.err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    train = {f["source"] for f in m["frames"] if f["split"] == "train"}
    held = {f["source"] for f in m["frames"] if f["split"] == "held_out"}
    assert len(train) == 4 and len(held) == 1 and not train & held
    assert {s["id"]: s["split"] for s in m["sources"]} == {f["source"]: f["split"] for f in m["frames"]}


def test_labels_are_mapped_cropped_and_masked(tmp_path, capsys):
    src, labels = tmp_path / "frames", tmp_path / "labels"
    for i in range(3):
        save(src / f"{i:03d}.png", circle_frame(i))
        lab = np.full((H, W), 50, np.uint8)
        lab[:, :100] = 21  # left half "liver" (id 21), right half id 50 (ignored)
        save(labels / f"{i:03d}.png", lab)
    (tmp_path / "map.json").write_text(json.dumps({"21": "liver", "50": None}))
    code, io = run_cli(["realset", str(src), "--out", str(tmp_path / "real"), "--labels", str(labels),
                        "--label-map", str(tmp_path / "map.json"), "--format", "png", "--quiet"], capsys)
    assert code == 0, io.err
    m = json.loads((tmp_path / "real" / "manifest.json").read_text())
    f = m["frames"][0]
    lab = np.asarray(Image.open(tmp_path / "real" / f["label"]))
    mask = np.asarray(Image.open(tmp_path / "real" / f"masks/{f['source']}.png")) > 127
    assert lab.shape == tuple(f["size"]) and (lab[~mask] == 255).all()
    h, w = lab.shape
    assert (lab[h // 2, 5:w // 2 - 3] == 0).all() and (lab[h // 2, w // 2 + 3:-5] == 255).all()


def _bad(tmp_path: Path, what: str) -> list[str]:
    src = tmp_path / "src"
    if what == "corrupt_video":
        p = src / "bad.mp4"
        p.parent.mkdir()
        p.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
        return [str(p)]
    if what in ("truncated_mp4", "truncated_mkv", "zero_frames"):
        ext = "mp4" if what == "truncated_mp4" else "mkv"
        data = _video(tmp_path / f"good.{ext}", seconds=3).read_bytes()
        src.mkdir()
        # an mp4 cut in half loses its index (at the end); an mkv decodes up to the cut; cut after
        # its header, it has no frame at all
        (src / f"cut.{ext}").write_bytes(data[: 600 if what == "zero_frames" else len(data) // 2])
        return [str(src / f"cut.{ext}")]
    if what == "not_media":
        src.mkdir()
        (src / "notes.txt").write_text("hello")
        return [str(src / "notes.txt")]
    if what == "no_frames":
        src.mkdir()
        (src / "notes.txt").write_text("hello")
        return [str(src)]
    if what == "broken_frame":
        save(src / "000.png", texture(0))
        (src / "001.png").write_bytes(b"not a png")
        return [str(src)]
    if what in ("label_size", "unknown_class"):
        for i in range(2):
            save(src / f"{i:03d}.png", texture(i))
            save(tmp_path / "labels" / f"{i:03d}.png", np.zeros((H // 2 if what == "label_size" else H, W), np.uint8))
        (tmp_path / "map.json").write_text(json.dumps({"0": "liver" if what == "label_size" else "tumour"}))
        return [str(src), "--labels", str(tmp_path / "labels"), "--label-map", str(tmp_path / "map.json")]
    if what in ("colour_labels_id_map", "bad_map_key"):
        save(src / "000.png", texture(0))
        lab = np.zeros((H, W, 3), np.uint8)
        lab[:, :50] = (255, 114, 114)
        save(tmp_path / "labels" / "000.png", lab)
        (tmp_path / "map.json").write_text(json.dumps({"21" if what == "colour_labels_id_map" else "red": "liver"}))
        return [str(src), "--labels", str(tmp_path / "labels"), "--label-map", str(tmp_path / "map.json")]
    if what == "class_table_alone":
        save(src / "000.png", texture(0))
        (tmp_path / "table.json").write_text(json.dumps({"classes": {"tumour": {"a_ref": [0.6, 0.3, 0.3]}}}))
        return [str(src), "--class-table", str(tmp_path / "table.json")]
    if what == "existing_out":
        save(src / "000.png", texture(0))
        (tmp_path / "real").mkdir()
        (tmp_path / "real" / "keep.txt").write_text("an earlier run")
        return [str(src)]
    raise AssertionError(what)


@pytest.mark.parametrize("what", ["corrupt_video", "truncated_mp4", "truncated_mkv", "zero_frames", "not_media",
                                  "no_frames", "broken_frame", "label_size", "unknown_class", "existing_out",
                                  "colour_labels_id_map", "bad_map_key", "class_table_alone"])
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, what):
    args = _bad(tmp_path, what)
    expected = {"corrupt_video": "cannot open video", "truncated_mp4": "cannot open video",
                "truncated_mkv": "is truncated", "zero_frames": "no decodable frames",
                "not_media": "neither a video", "no_frames": "holds no frames", "broken_frame": "cannot read frame",
                "label_size": "is 60x200 but its frame is 120x200", "unknown_class": "unknown class 'tumour'",
                "existing_out": "already holds other data", "colour_labels_id_map": "key it by colour",
                "bad_map_key": "'red' is neither a class id", "class_table_alone": "--class-table names the classes"}[what]
    before = sorted(p.name for p in tmp_path.iterdir())
    code, io = run_cli(["realset", *args, "--out", str(tmp_path / "real"), "--quiet"], capsys)
    assert code == 2
    lines = io.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sim2real: error:") and expected in lines[0], io.err
    assert "Errno" not in lines[0]  # FFmpeg's reason without its error number
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no output, no temporary folder
    if what == "existing_out":
        assert [p.name for p in (tmp_path / "real").iterdir()] == ["keep.txt"]


@pytest.mark.parametrize("what", ["corrupt_video", "truncated_mp4"])
def test_unopenable_video_fails_before_any_progress_bar(tmp_path, capsys, what):
    # without --quiet: a video the container library cannot open is refused before its bar is drawn,
    # so captured stderr holds the error line alone (no carriage-return fragment of a cleared bar)
    code, io = run_cli(["realset", *_bad(tmp_path, what), "--out", str(tmp_path / "real")], capsys)
    assert code == 2
    assert "\r" not in io.err and io.err.count("\n") == 1, repr(io.err)
    assert io.err.startswith("sim2real: error: cannot open video"), io.err
