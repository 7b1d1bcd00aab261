"""``data.intrinsics``: a calibrated endoscope's pinhole intrinsics for every random view
(fresh views, view pools, linear paths), read back from YAML and refused in one line when they do
not fit the image."""

import numpy as np
import pytest
from train_data import tiny_config

import sim2real.data.viewpool as viewpool
from sim2real.config import DataConfig, save_yaml, to_dict
from sim2real.data.pairs import TrainPairs
from sim2real.data.real import RealImages
from sim2real.data.sources import resolve_scenes
from sim2real.data.triplets import TrainTriplets
from sim2real.errors import UserError
from sim2real.presets import load_config
from sim2real.validation import validate

FX, FY, CX, CY = 40.0, 44.0, 26.0, 13.0  # off-centre, non-square pixels, in pixels of 32x64
HAND_K = [[FX, 0, CX], [0, FY, CY], [0, 0, 1]]


def check_seen_through(g):
    """The G-buffer carries the calibrated K, and its points lie on the rays of that K: in the
    camera frame a pixel's point is ((col + 0.5 - cx) / fx, (row + 0.5 - cy) / fy, 1) times its
    depth (hand-written unprojection)."""
    np.testing.assert_array_equal(g.K, HAND_K)
    rows, cols = np.nonzero(g.object_id >= 0)
    assert len(rows) > 100
    z = g.depth[rows, cols].astype(np.float64)
    hand = np.stack([(cols + 0.5 - CX) / FX * z, (rows + 0.5 - CY) / FY * z, z], axis=1)
    R, t = g.world_to_camera[:3, :3], g.world_to_camera[:3, 3]
    # the 1 mm rule (fp16 geometry in pools rounds by at most 2**-11 of 50-200 mm)
    np.testing.assert_allclose(g.points[rows, cols] @ R.T + t, hand, atol=0.2)


def test_fresh_random_views_and_linear_paths_see_through_the_calibrated_intrinsics(train_inputs):
    scenes, real = train_inputs
    cfg = DataConfig(height=32, width=64, intrinsics=[FX, FY, CX, CY], workers=0)
    sources = resolve_scenes([scenes], cfg.height, cfg.width)
    ds = TrainPairs(sources, RealImages(real), cfg, seed=0)
    for step in range(2):
        index, g = ds._view(sources[0], ds.rng(step))
        assert index is None  # a fresh pose ray-cast now
        check_seen_through(g)

    # without them: the centred square-pixel K of the 75 degree field of view
    plain = TrainPairs(sources, RealImages(real), DataConfig(height=32, width=64, workers=0), seed=0)
    f = 32 / np.tan(np.radians(75 / 2))
    np.testing.assert_allclose(plain._view(sources[0], plain.rng(0))[1].K, [[f, 0, 32], [0, f, 16], [0, 0, 1]])


def test_the_video_methods_linear_paths_use_them(video_train_inputs, monkeypatch):
    import sim2real.data.triplets as triplets

    scenes, real = video_train_inputs
    cfg = DataConfig(height=32, width=64, intrinsics=[FX, FY, CX, CY], workers=0)
    drawn = []
    real_path = triplets.linear_path
    monkeypatch.setattr(triplets, "linear_path", lambda *a, **k: drawn.append(real_path(*a, **k)) or drawn[-1])
    tri = TrainTriplets(resolve_scenes([scenes], cfg.height, cfg.width), RealImages(real), cfg, seed=0)
    tri[0]
    assert len(drawn) == 1 and len(drawn[0]) == 3
    for cam in drawn[0]:
        np.testing.assert_array_equal(cam.K, HAND_K)


def test_a_view_pool_is_drawn_with_the_intrinsics_and_keyed_by_them(train_inputs, monkeypatch, tmp_path):
    monkeypatch.setenv("SIM2REAL_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(viewpool, "worker_count", lambda jobs=None, reserve=0: 1)
    scenes, _ = train_inputs
    pools = {}
    for name, values in (("calibrated", [FX, FY, CX, CY]), ("fov", None)):
        cfg = DataConfig(height=32, width=64, view_pool=2, intrinsics=values)
        sources = resolve_scenes([scenes], cfg.height, cfg.width)
        viewpool.attach_view_pools(sources, cfg, 0, progress=False)
        pools[name] = sources[0].pool
    assert pools["calibrated"].folder != pools["fov"].folder
    assert "intrinsics" not in pools["fov"].spec  # pools cached before keep their keys
    for k in range(2):
        check_seen_through(pools["calibrated"].view(k))


def test_intrinsics_round_trip_through_yaml_and_bad_ones_are_refused(tmp_path):
    cfg = tiny_config(data__intrinsics="[60, 62, 70, 30]")  # as --set writes them; tiny is 64x128
    assert cfg.data.intrinsics == [60.0, 62.0, 70.0, 30.0]
    validate(cfg)
    save_yaml(cfg, tmp_path / "c.yaml")
    assert load_config(tmp_path / "c.yaml").data.intrinsics == [60.0, 62.0, 70.0, 30.0]
    assert to_dict(tiny_config())["data"]["intrinsics"] is None
    for value, words in (("[60, 62, 200, 30]", "data.intrinsics (pixels of 64x128): the principal point (200, 30) "
                                               "lies outside the 128x64 image"),
                         ("[60, 62, 70]", "data.intrinsics (pixels of 64x128): intrinsics are four numbers"),
                         ("[0.5, 62, 70, 30]", "horizontal field of view of 179.1 degrees")):  # atan(140)+atan(116)
        with pytest.raises(UserError, match=words.replace("(", r"\(").replace(")", r"\)")):
            validate(tiny_config(data__intrinsics=value))
    for value in ("wide", "[1, two, 3, 4]", "[true, 1, 1, 1]"):
        with pytest.raises(UserError, match="config key 'data.intrinsics' expects a list of numbers or null"):
            tiny_config(data__intrinsics=value)


def test_a_run_trained_with_them_keeps_them_and_is_evaluated_through_them(tmp_path, train_inputs, monkeypatch,
                                                                         one_torch_thread):
    """Two steps of the tiny preset (64x128) with intrinsics: the run's config keeps them, and the
    evaluation's random views and trajectories take them."""
    import sim2real.inference.evaluate as evaluate_mod
    from sim2real.engine.trainer import Trainer

    scenes, real = train_inputs
    values = [60.0, 62.0, 70.0, 30.0]
    cfg = tiny_config(iterations=2, checkpoint_every=2, log_every=1, image_every=2, device="cpu", data__workers=0,
                      data__intrinsics=str(values))
    trainer = Trainer(cfg, [scenes], real, tmp_path / "run", progress=False)
    try:
        trainer.train()
    finally:
        trainer.close()
    assert load_config(tmp_path / "run" / "config.yaml").data.intrinsics == values
    seen = []
    monkeypatch.setattr(evaluate_mod, "run_stages", lambda *a, **k: seen.append(a[8]) or {})
    evaluate_mod.evaluate(tmp_path / "run", [str(scenes)], real, tmp_path / "eval", device="cpu")
    (H, W, K), = seen
    assert (H, W) == (64, 128)
    np.testing.assert_array_equal(K, [[60, 0, 70], [0, 62, 30], [0, 0, 1]])
