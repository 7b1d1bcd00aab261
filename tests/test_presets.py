"""Named presets: one table, each valid for every method, each round-tripping through YAML."""

from __future__ import annotations

import pytest
import yaml

from sim2real.config import differences, save_yaml, to_dict
from sim2real.errors import UserError
from sim2real.presets import METHOD_PRESETS, PRESETS, budgeted, default_preset, load_config, preset
from sim2real.validation import validate


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_is_valid_for_every_method_and_reads_back(name, tmp_path):
    for method in METHOD_PRESETS:
        cfg = preset(name, method)
        validate(cfg)
        save_yaml(cfg, tmp_path / "c.yaml")
        assert yaml.safe_load((tmp_path / "c.yaml").read_text())["method"]["name"] == METHOD_PRESETS[method][0]
        assert to_dict(load_config(tmp_path / "c.yaml")) == to_dict(cfg), (name, method)


def test_the_cpu_preset_is_small_with_the_cpu_recipe():
    """``cpu`` differs from ``small`` in exactly the keys its docstring lists."""
    changed = {k: (a, b) for k, a, b in differences(preset("small"), preset("cpu"))}
    assert changed == {
        "method.vc_start": (2000, 300), "method.target_grad": (True, False), "method.tex_edges": (0.0, 1.0),
        "method.texture.init_noise": (0.0, 1.0),
        "checkpoint_every": (1000, 100), "log_every": (50, 20), "image_every": (500, 100),
        "generator.filters": (32, 16), "discriminator.filters": (32, 16),
        "loss.ab_structure": ("ms_ssim", "edges"), "loss.edge_power": (1.0, 2.0), "optim.lr_net": (1e-4, 1e-3),
        "data.view_pool": (3000, 0),
    }
    # init_noise_sigma 1.5 is set by the recipe and equals the default, so it is no difference
    assert preset("cpu").method.texture.init_noise_sigma == 1.5


def test_cpu_lines_is_cpu_with_the_drawn_line_net():
    changed = {k: (a, b) for k, a, b in differences(preset("cpu"), preset("cpu-lines"))}
    assert changed == {"method.texture.init_noise": (1.0, 0.0), "method.texture.init_lines": (0.0, 1.0),
                       "method.tex_edges": (1.0, 3.0), "loss.edge_contrast": (0.02, 0.08)}
    assert preset("cpu-lines").method.texture.init_lines_sigma == 4.0
    assert "hand-drawn prior, not learned detail" in " ".join(PRESETS["cpu-lines"].__doc__.split())


def test_a_method_without_the_recipes_keys_gets_the_shared_part():
    """ReCycle has no view consistency and no texture: the CPU recipe's method keys are skipped,
    the rest applies."""
    changed = {k for k, _, _ in differences(preset("small", "recycle"), preset("cpu-lines", "recycle"))}
    assert changed == {"checkpoint_every", "log_every", "image_every", "generator.filters", "discriminator.filters",
                       "loss.ab_structure", "loss.edge_power", "loss.edge_contrast", "optim.lr_net", "data.view_pool"}
    assert {k for k, _, _ in differences(preset("small", "of_unit"), preset("cpu", "of_unit"))} >= {"method.vc_start"}


def test_demo_and_benchmark_pick_the_preset_by_the_device():
    assert default_preset(cuda=True) == "paper" and default_preset(cuda=False) == "cpu"
    run = budgeted("cpu", "ours", "cpu")
    assert {k for k, _, _ in differences(preset("cpu"), run)} == {"device", "iterations"}
    assert budgeted("tiny").checkpoint_every == 5


def test_unknown_names_are_refused_in_one_line():
    with pytest.raises(UserError, match="unknown preset 'gpu' \\(choose from paper, small, tiny, cpu, cpu-lines\\)"):
        preset("gpu")
    with pytest.raises(UserError, match="unknown method 'cyclegan'"):
        preset("cpu", "cyclegan")
