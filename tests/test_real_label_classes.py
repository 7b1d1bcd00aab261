"""Real labels onto the class table: colour masks of seven classes (one the user's own) mapped by
a label map, stored with the table's label ids, and segmenters that learn every class the labels
and the scene share."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from sim2real.cli.main import main
from sim2real.errors import UserError
from sim2real.footage.labels import read_label_map
from sim2real.inference import dice as dice_mod
from sim2real.inference.realimages import find_real, shared_classes
from sim2real.inference.report import class_dice_blocks
from sim2real.inference.stages import ViewSet, segmentation_stage
from sim2real.scene.classes import ClassTable

H, W = 64, 128  # frames: a 2 x 4 grid of 32-pixel cells
# class -> (label colour in the dataset's masks, the tissue colour the frames show)
CLASSES = {"liver": ("#ff7272", (150, 40, 40)), "fat": ("#bab74b", (230, 200, 90)),
           "gallbladder": ("#ffa0a5", (90, 140, 60)), "stomach": ("#e7469c", (220, 130, 170)),
           "instrument": ("#aaff00", (190, 190, 200)), "vessel": ("#003280", (110, 20, 160)),
           "tumour": ("#ff00ff", (60, 170, 200))}
UNMAPPED = ("#7f7f7f", (120, 120, 60))  # the eighth cell: a colour the map leaves out
EXPECTED_IDS = {"liver": 0, "fat": 1, "gallbladder": 4, "stomach": 5, "instrument": 12, "vessel": 13, "tumour": 16}


def rgb(hex_colour: str) -> tuple[int, int, int]:
    return tuple(int(hex_colour[i:i + 2], 16) for i in (1, 3, 5))


def frame_and_label(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    cells = list(CLASSES) + [None]
    order = [cells[i] for i in rng.permutation(8)]
    img = np.empty((H, W, 3), np.uint8)
    lab = np.empty((H, W, 3), np.uint8)
    for k, name in enumerate(order):
        y, x = 32 * (k // 4), 32 * (k % 4)
        colour, tissue = CLASSES[name] if name else UNMAPPED
        img[y:y + 32, x:x + 32] = np.clip(np.array(tissue) + rng.normal(0, 12, (32, 32, 3)), 0, 255)
        lab[y:y + 32, x:x + 32] = rgb(colour)
    return img, lab, order


@pytest.fixture(scope="module")
def labelled_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("labels")
    rng = np.random.default_rng(0)
    layouts = {}
    for src in ("a", "b"):
        for i in range(12):
            img, lab, order = frame_and_label(rng)
            for d, a in (("src", img), ("labels", lab)):
                (root / d / src).mkdir(parents=True, exist_ok=True)
                Image.fromarray(a).save(root / d / src / f"{i:03d}.png")
            layouts[(src, i)] = order
    label_map = {c: name for name, (c, _) in CLASSES.items()} | {UNMAPPED[0]: None}
    (root / "map.json").write_text(json.dumps(label_map))
    (root / "table.json").write_text(json.dumps({"classes": {"tumour": {"a_ref": [0.6, 0.3, 0.3]}}}))
    assert main(["realset", str(root / "src"), "--out", str(root / "real"), "--labels", str(root / "labels"),
                 "--label-map", str(root / "map.json"), "--class-table", str(root / "table.json"),
                 "--format", "png", "--height", str(H), "--dup-distance", "-1", "--quiet"]) == 0
    return root, layouts


def test_colour_labels_are_stored_with_the_class_tables_ids(labelled_set):
    root, layouts = labelled_set
    m = json.loads((root / "real" / "manifest.json").read_text())
    assert {k: v["label"] for k, v in m["label_classes"].items()} == EXPECTED_IDS
    assert len(m["frames"]) == 24 and all(f["label"] for f in m["frames"])
    for f in m["frames"][:6]:
        lab = np.asarray(Image.open(root / "real" / f["label"]))
        assert lab.shape == (H, W)
        src = f["source"].split("_")[-1]
        for k, name in enumerate(layouts[(src, f["index"])]):
            y, x = 32 * (k // 4) + 16, 32 * (k % 4) + 16  # each cell's centre
            assert lab[y, x] == (EXPECTED_IDS[name] if name else 255), (f["file"], name)


def test_segmenters_learn_every_class_the_scene_shares(labelled_set, tmp_path, monkeypatch):
    root, _ = labelled_set
    monkeypatch.setenv("SIM2REAL_CACHE", str(tmp_path / "cache"))
    rs = find_real(root / "real")
    scene_table = ClassTable.from_file(root / "table.json").subset(
        ["liver", "fat", "gallbladder", "stomach", "instrument", "tumour", "abdominal_wall"])  # no vessel
    classes = shared_classes(rs, [scene_table])
    assert classes == {"liver": 0, "fat": 1, "gallbladder": 4, "stomach": 5, "instrument": 12, "tumour": 16}
    s = SimpleNamespace(seg_height=16, seg_width=32, seg_iterations=120, seg_batch=8, seg_holdout=0.25, seed=0,
                        seg_check_every=50, seg_seeds=1, seg_max_stderr=0.02)
    models, info = dice_mod.segmenters(rs.labelled, s, "cpu", progress=False, say=lambda m: None,
                                       masks=[rs.mask_of(p) for p, _ in rs.labelled], classes=classes)
    per_class = info["per_seed"][0]["held_out_dice_classes"]
    assert set(per_class) == set(classes) and models[0].head.out_channels == 6
    # measured: held-out Dice 0.81 (fat) to 0.99 (liver) at 120 steps; at 80 steps fat was 0.59
    assert min(per_class.values()) > 0.7, per_class
    assert info["per_seed"][0]["held_out_dice"] == pytest.approx(per_class["liver"])
    # scored on fresh frames whose ground truth is known: every class found; one absent is None
    rng = np.random.default_rng(5)
    frames, views = [], []
    for _ in range(6):
        img, _, order = frame_and_label(rng)
        ids = np.array([EXPECTED_IDS[n] if n else -1 for n in order]).reshape(2, 4)
        ids[ids == EXPECTED_IDS["tumour"]] = -1  # views without tumour (it is in no view)
        frames.append(img)
        views.append(np.kron(ids, np.ones((32, 32), int)))
    d = dice_mod.class_dice(models, frames, views, classes, s)
    assert d["tumour"] is None
    assert all(d[c]["value"] > 0.6 for c in classes if c != "tumour"), d  # measured 0.77 (fat) to 0.98
    # the evaluation's stage: the liver's Dice as always, each shared class's beside it (cached segmenters)
    vs = ViewSet({"model": frames, "a_ref": frames}, {"model": frames, "a_ref": frames}, ["default"],
                 [v == 0 for v in views], views)
    seg = segmentation_stage(rs, vs, s, "cpu", ["model", "a_ref"], progress=False, classes=classes)
    assert seg["info"]["class_dice"]["fat"]["model"] == pytest.approx(d["fat"]["value"])
    assert seg["info"]["class_dice"]["tumour"] == {"model": None, "a_ref": None}
    assert seg["rows"]["model"] == pytest.approx(d["liver"]["value"])
    # the report gives each class's row: the frames' Dice per row and the held-out real images'
    blocks = class_dice_blocks({"dice_info": seg["info"]})
    header, table = blocks[-1][1], {r[0]: r[1:] for r in blocks[-1][2]}
    assert header == ["class", "translated views", "a_ref (untranslated)", "held-out real images"]
    assert list(table) == list(classes) and table["tumour"] == ["n/a", "n/a", f"{per_class['tumour']:.4g}"]
    assert table["fat"] == [f"{d['fat']['value']:.4g}"] * 2 + [f"{per_class['fat']:.4g}"]
    assert class_dice_blocks({"dice_info": {k: v for k, v in seg["info"].items() if k != "class_dice"}}) == []


def test_a_class_with_another_id_in_the_scene_is_refused(labelled_set):
    root, _ = labelled_set
    rs = find_real(root / "real")
    other = ClassTable.defaults().with_entries({"tumour": {"a_ref": [0.6, 0.3, 0.3], "label": 40}})
    with pytest.raises(UserError, match="class 'tumour' has label id 16 in the real set's labels but 40"):
        shared_classes(rs, [other])


def test_label_map_ids_and_colours(tmp_path):
    (tmp_path / "m.json").write_text(json.dumps({"21": "liver", "#AAFF00": "instrument", "50": None}))
    lm = read_label_map(tmp_path / "m.json")
    assert lm.lut[21] == 0 and lm.lut[50] == 255 and lm.lut[22] == 255
    assert lm.colours == {0xAAFF00: 12} and list(lm.classes) == ["liver", "instrument"]
    img = np.zeros((2, 2, 3), np.uint8)
    img[0, 0] = (170, 255, 0)
    assert lm.map_colours(img, tmp_path / "x.png").tolist() == [[12, 255], [255, 255]]
