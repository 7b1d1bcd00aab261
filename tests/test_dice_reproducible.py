"""A Dice that reproduces: segmenters trained in two fresh caches give the same weights and the same
Dice, with a fixed number of steps; the cache key holds the library versions."""

import numpy as np
import pytest
import torch
from eval_data import labelled_real_dir

from sim2real.data.real import load_rgb
from sim2real.inference import dice as dice_mod
from sim2real.inference.evaluate import EvalSettings
from sim2real.inference.realimages import find_real, fit_image

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_dice_equal_across_two_fresh_caches(tmp_path_factory, monkeypatch):
    base = tmp_path_factory.getbasetemp()
    labelled = find_real(labelled_real_dir(base)).labelled
    s = EvalSettings(seg_iterations=12, seg_seeds=2, seg_check_every=5)
    frames = [load_rgb(p) for p, _ in labelled]
    gt = np.stack([fit_image((np.array(load_rgb(lp))[..., 0] == 0).astype(np.uint8), 32, 64, nearest=True).astype(bool)
                   for _, lp in labelled])
    results = []
    for k in range(2):
        monkeypatch.setenv("SIM2REAL_CACHE", str(tmp_path_factory.mktemp(f"fresh_cache_{k}")))
        torch.set_num_threads(1 + k)  # the caller's thread count must not matter
        models, info = dice_mod.segmenters(labelled, s, "cpu", progress=False, say=lambda m: None)
        assert torch.get_num_threads() == 1 + k  # restored after training
        assert all(not m["cached"] and m["steps"] == 12 for m in info["per_seed"])
        results.append((dice_mod.dice_of(models, frames, gt, s)["per_seed"],
                        [m.state_dict()["head.weight"].clone() if "head.weight" in m.state_dict()
                         else next(iter(m.state_dict().values())).clone() for m in models]))
    torch.set_num_threads(1)
    assert results[0][0] == results[1][0]
    assert all(torch.equal(a, b) for a, b in zip(results[0][1], results[1][1]))


def test_cache_key_holds_library_versions_and_settings(tmp_path_factory, monkeypatch):
    labelled = find_real(labelled_real_dir(tmp_path_factory.getbasetemp())).labelled
    spec = {"iterations": 12, "libraries": dice_mod.library_versions()}
    key = dice_mod.cache_key(labelled, spec)
    assert dice_mod.cache_key(labelled, dict(spec)) == key
    assert dice_mod.cache_key(labelled, {**spec, "iterations": 13}) != key
    monkeypatch.setattr(torch, "__version__", "0.0.1")
    assert dice_mod.library_versions()["torch"] == "0.0.1"
    assert dice_mod.cache_key(labelled, {"iterations": 12, "libraries": dice_mod.library_versions()}) != key


def test_an_unstable_dice_is_the_mean_with_the_seeds_range_beside_it():
    """0.93 / 0.86 / 0.90: mean 0.89667, sample variance ((0.03333)^2 + (0.03667)^2 + (0.00333)^2) / 2
    = 0.0012333, standard deviation 0.035119, standard error 0.035119 / sqrt(3) = 0.020276 > 0.02:
    unstable, and the value is still the mean. 0.95 / 0.97: standard error 0.01414 / sqrt(2) = 0.01."""
    from sim2real.inference.dice import summarise

    d = summarise([0.93, 0.86, 0.90], 0.02)
    assert d["value"] == pytest.approx(0.896667, abs=1e-6) and d["spread"] == pytest.approx(0.07)
    assert d["stderr"] == pytest.approx(0.020276, abs=1e-6)
    assert d["stable"] is False and "0.860-0.930" in d["reason"] and "the mean is shown" in d["reason"]
    assert summarise([0.93, 0.86, 0.90], 0.021)["stable"]  # the same seeds under a looser bound
    ok = summarise([0.95, 0.97], 0.02)
    assert ok["stable"] and ok["reason"] is None and ok["value"] == pytest.approx(0.96)
    assert ok["stderr"] == pytest.approx(0.01)
    one = summarise([0.5], 0.0)  # one seed: no scatter to measure
    assert one["stderr"] == 0.0 and one["stable"]
    assert summarise([], 0.02)["value"] is None


def test_the_report_gives_a_dice_with_its_standard_error_and_the_seeds():
    """The report's Dice cell: the mean to 4 digits, then '± ' and the standard error to 3 decimals;
    one seed (standard error 0) gives the bare mean."""
    from sim2real.inference.dice import summarise
    from sim2real.inference.report import _dice_row

    m = {"dice_info": {"rows": {"model": summarise([0.95, 0.97], 0.02), "a_ref": summarise([0.5], 0.02)}},
         "reasons": {"dice": None}}
    label, value, note = _dice_row(m, "model", "Dice", "mean over 2")
    assert value == "0.96 ± 0.010" and note == "mean over 2 (seeds 0.950, 0.970)"
    assert _dice_row(m, "a_ref", "Dice", "one")[1] == "0.5"
