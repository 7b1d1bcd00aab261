"""The revisit protocol for real: a time-dependent method translates the backward half T..1 itself,
continuing its state; a time-independent one may reuse its forward frames (and equals them)."""

from __future__ import annotations

import pytest
from toy_methods import DriftConfig, ToyConfig, toy_methods  # noqa: F401  (fixture)
from train_data import real_dir, scene_dir

from sim2real.inference.evaluate import EvalSettings, evaluate
from sim2real.presets import preset

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _toy_run(base, section, name):
    from sim2real.engine.trainer import Trainer

    cfg = preset("tiny")
    cfg.method, cfg.iterations, cfg.checkpoint_every, cfg.device = section, 1, 1, "cpu"
    trainer = Trainer(cfg, [scene_dir(base, 11)], real_dir(base), base / name, progress=False)
    trainer.train()
    trainer.close()
    return base / name


def _evaluate(base, run, out):
    s = EvalSettings(views=2, frames=12, anchors=False, seed=0)
    return evaluate(run, [scene_dir(base, 11)], real_dir(base), out, settings=s, device="cpu", progress=False)


def test_history_dependent_method_fails_the_revisit_equality(toy_methods, tmp_path):
    still = _evaluate(tmp_path, _toy_run(tmp_path, ToyConfig(), "still"), tmp_path / "e_still")
    drift = _evaluate(tmp_path, _toy_run(tmp_path, DriftConfig(drift_mm=0.3), "drift"), tmp_path / "e_drift")
    # the time-independent toy: forward frames reused, revisit = forward, and a consistent video
    assert still["revisit"]["backward_frames"].startswith("reused")
    assert still["revisit"]["orb"]["1"] == still["orb"]["1"]
    assert still["orb"]["1"]["accuracy"] > 0.5
    # the drifting toy translates 1..T, T..1 itself: neighbours agree (0.3 mm apart), but a view
    # revisited up to 22 frames later has its pattern moved by up to 6.6 mm
    assert drift["revisit"]["backward_frames"].startswith("translated by the method")
    fwd, rev = drift["orb"]["1"], drift["revisit"]["orb"]["1"]
    assert fwd["accuracy"] > 0.5
    assert rev["accuracy"] < 0.5 * fwd["accuracy"], (fwd, rev)
    assert drift["revisit"]["of_error"] != pytest.approx(drift["of_error"])
    name = next(iter(drift["per_scene"]))
    assert (tmp_path / "e_drift" / "videos" / f"{name}_revisit.mp4").is_file()
