"""The evaluation's stages one by one, on a tiny scene at 64x128 with a stand-in 'model' whose
translation is the ceiling itself: every row the model shares with the ceiling must come out equal."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from eval_data import labelled_real_dir
from train_data import scene_dir

from sim2real.inference.anchors import Anchors
from sim2real.inference.evaluate import EvalSettings
from sim2real.inference.realimages import find_real
from sim2real.inference.rows import ROWS
from sim2real.inference.metrics_json import assemble_metrics
from sim2real.inference.realism import realism_stage, weight_free_realism
from sim2real.inference.stages import (
    VIEW_INDEX0,
    ViewSet,
    consistency_stage,
    report_stage,
    segmentation_stage,
    views_stage,
)
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import intrinsics_from_fov
from sim2real.scene.scene import Scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")
SIZE = (64, 128, intrinsics_from_fov(128, 64, 75.0))  # (H, W, the views' K)


class CeilingModel:
    """Translates a view into the ceiling's frame of it (two 'styles': the ceiling and its negative)."""

    time_independent = True

    def __init__(self, anchors: Anchors):
        self.anchors = anchors
        self.views = 0

    def translate_views(self, name, gbuffers, styles, seed, batch):
        frames = []
        for g in gbuffers:
            frames.append(self.anchors.ceiling(g, VIEW_INDEX0 + self.views))
            self.views += 1
        return {"": frames, "neg": [255 - f for f in frames]}

    def sequence(self, name, batch):
        state = {"t": 0}

        def translate(chunk):
            out = []
            for g in chunk:
                out.append(self.anchors.ceiling(g, state["t"]))
                state["t"] += 1
            return out
        return SimpleNamespace(translate=translate)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    d = scene_dir(base, 11)
    sc = Scene.load(d)
    anchors = {sc.name: Anchors(sc, seed=0, pool=4)}
    s = EvalSettings(views=3, frames=6, orb_max_k=3, batch=4, seg_iterations=2, seg_seeds=2, seg_check_every=1,
                     samples=2, workers=1)
    return SimpleNamespace(base=base, scenes=[(sc, d)], casters={sc.name: RayCaster(sc)}, anchors=anchors,
                           model=CeilingModel(anchors[sc.name]), s=s, name=sc.name)


@pytest.fixture(scope="module")
def views(setup):
    real = [np.full((64, 128, 3), 90, np.uint8)]
    return views_stage(setup.model, setup.scenes, setup.casters, setup.anchors, real, setup.s, ROWS, SIZE, progress=False)


def test_views_stage(views):
    assert set(views.shown) == set(ROWS) and all(len(v) == 3 for v in views.shown.values())
    assert views.variants == ["default", "neg"]
    assert len(views.scored["model"]) == 6  # variant after variant
    assert np.array_equal(views.scored["model"][4], 255 - views.shown["model"][1])
    for i in range(3):
        assert np.array_equal(views.shown["model"][i], views.shown["ceiling"][i])
        assert not np.array_equal(views.shown["ceiling"][i], views.shown["floor"][i])
    assert len(views.liver) == 3 and views.liver[0].shape == (64, 128) and views.liver[0].dtype == bool


def test_realism_stage_identical_sets():
    rng = np.random.default_rng(0)
    real = [rng.integers(0, 256, (16, 24, 3), dtype=np.uint8) for _ in range(4)]
    flat = [np.full((16, 24, 3), 128, np.uint8)] * 4
    vs = ViewSet(shown={"model": real, "a_ref": flat}, scored={"model": real, "a_ref": flat}, variants=["default"])
    status = {"available": False, "path": None, "reason": "no weights here"}
    r = realism_stage(vs, real, None, status, EvalSettings(), ["model", "a_ref"])
    assert r["reason"] == "no weights here" and r["fid"]["fid"] is None and r["fid_info"]["n_gen"] == 4
    assert r["rows"]["model"]["proxy"] == pytest.approx(0.0, abs=1e-12)  # the real images themselves
    assert r["rows"]["model"]["detail"] == pytest.approx(1.0)
    assert r["rows"]["a_ref"]["detail"] == 0.0 and r["rows"]["a_ref"]["proxy"] > 0.3
    # the proxy's real row, one half of the real images against the other: two halves of 8 draws
    # of the same noise are near each other, far nearer than the flat a_ref is to the noise
    many = [rng.integers(0, 256, (16, 24, 3), dtype=np.uint8) for _ in range(16)]
    r = realism_stage(vs, many, None, status, EvalSettings(), ["model", "a_ref"])
    assert 0.0 < r["real_held_out"]["proxy"] < 0.1 * r["rows"]["a_ref"]["proxy"]
    same = realism_stage(vs, [real[0]] * 6, None, status, EvalSettings(), ["model", "a_ref"])
    assert same["real_held_out"]["proxy"] == pytest.approx(0.0, abs=1e-12)  # identical halves
    one = realism_stage(vs, real[:1], None, status, EvalSettings(), ["model", "a_ref"])
    assert one["real_held_out"]["proxy"] is None  # no half to compare with


def test_segmentation_stage(setup, views, tmp_path):
    (tmp_path / "a.png").write_bytes((labelled_real_dir(setup.base) / "images" / "frame_00.png").read_bytes())
    r = segmentation_stage(find_real(tmp_path), views, setup.s, "cpu", ROWS, progress=False)
    assert r["dice"]["dice"] is None and "labels" in r["reason"] and r["rows"] == {}
    r = segmentation_stage(find_real(labelled_real_dir(setup.base)), views, setup.s, "cpu", ROWS, progress=False)
    assert set(r["rows"]) == set(ROWS) and r["info"]["n_train"] == 5 and r["info"]["n_eval"] == 6
    model, ceiling = r["info"]["rows"]["model"], r["info"]["rows"]["ceiling"]
    assert len(model["per_seed"]) == 2
    # the model's scored set is the ceiling's views plus their negatives: its per-seed Dice is the
    # mean of the two halves, so it differs from the ceiling's unless the negatives score the same
    assert r["dice"]["dice_ceiling"] == ceiling["value"] and r["dice"]["dice"] == model["value"]


@pytest.fixture(scope="module")
def consistency(setup, tmp_path_factory):
    out = tmp_path_factory.mktemp("cons")
    return out, consistency_stage(setup.model, setup.scenes, setup.casters, setup.anchors, setup.s, ROWS, out, SIZE,
                                  progress=False)


def test_consistency_stage_model_equals_ceiling(setup, consistency):
    out, c = consistency
    rows = c["per_scene"][setup.name]["rows"]
    assert c["per_scene"][setup.name]["frames"] == 6 and c["ks"] == [1, 2, 3, 5, 10]
    for k in ("1", "2", "3"):
        assert rows["model"]["orb_curve"][k] == rows["ceiling"]["orb_curve"][k]
    assert rows["ceiling"]["orb_curve"]["1"]["correct"] > 0
    assert rows["model"]["of_error"] == rows["ceiling"]["of_error"]
    assert rows["model"]["of_error_vs_ceiling"] == 0.0
    assert rows["model"]["orb_curve"]["5"]["pairs"] == 1 and rows["model"]["orb_curve"]["10"]["pairs"] == 0
    assert (out / "videos" / f"{setup.name}.mp4").is_file() and (out / "videos" / f"{setup.name}_floor.mp4").is_file()


def test_report_stage(setup, views, consistency, tmp_path):
    _, c = consistency
    real = [np.full((64, 128, 3), 90, np.uint8)]
    status = {"available": False, "path": None, "reason": "no weights"}
    realism = realism_stage(views, real, None, status, setup.s, ROWS)
    seg = {"dice": {"dice": None, "dice_a_ref": None, "dice_real_train": None, "dice_real_held_out": None,
                    "dice_ceiling": None}, "info": {"n_train": 0, "n_eval": 6, "rows": {}}, "rows": {}, "reason": "none"}
    header = {"format": "f", "run": {"dir": "r", "checkpoint": "c", "step": 1, "method": "m", "device": "cpu",
                                          "train_height": 64, "train_width": 128}, "inputs": {"real": {"dir": "x", "images": 1, "images_used": 1,
                                                                     "labelled": 0, "stand_in": False}}}
    m = assemble_metrics(header=header, s=setup.s, rows_shown=ROWS, realism=realism, seg=seg, cons=c,
                         time_independent=True, real_is_stand_in=False, anchor_options={}, seconds={"total": 1.0})
    assert m["rows"]["model"]["orb_1_correct"] == m["rows"]["ceiling"]["orb_1_correct"]
    assert m["position"]["orb_1_correct"]["position"] in (None, 1.0)
    assert any("not the stand-in" in w for w in m["warnings"])
    assert m["reasons"]["dice"] == "none" and "ORB-10: no frame pair" in m["reasons"]["orb"]
    report_stage(m, tmp_path, views, real, c["samples"], setup.s)
    assert json.loads((tmp_path / "metrics.json").read_text()) == m
    assert (tmp_path / "samples" / "views.png").is_file() and "ORB-1" in (tmp_path / "report.md").read_text()


def test_weight_free_realism_rows():
    """Every row is compared with half of the real images, the other half is the null row; flat
    frames are told apart from textured real ones, the real images' other half is not."""
    rng = np.random.default_rng(3)
    real = [rng.integers(60, 200, (24, 32, 3), dtype=np.uint8) for _ in range(16)]
    flat = [np.full((24, 32, 3), 128, np.uint8)] * 8
    s = EvalSettings(c2st_steps=40, realism_kid=True)
    m = weight_free_realism({"model": real[:8], "a_ref": flat}, real, s, ["model", "a_ref"])
    c = m["c2st"]
    assert c["better"] == "lower" and c["null"] == 0.5 and set(c["rows"]) == {"model", "a_ref", "real_held_out"}
    assert c["rows"]["a_ref"] == 1.0 and c["details"]["a_ref"]["n_test"] == 8
    assert c["rows"]["real_held_out"] < 1.0
    k = m["random_kid"]
    assert k["rows"]["a_ref"] > 10 * max(abs(k["rows"]["real_held_out"]), 1e-6)
    off = weight_free_realism({"model": real[:8]}, real, EvalSettings(c2st_steps=0), ["model"])
    assert off["c2st"]["rows"]["model"] is None and "switched off" in off["c2st"]["reason"]
    assert "off by default" in off["random_kid"]["reason"]
