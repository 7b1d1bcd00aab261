"""Named training presets, in one place, and the loading of configs with the method registry.

A preset is a function ``(method) -> TrainConfig``: the same recipe for every method, with the
method's own section at the preset's size (:meth:`sim2real.config.MethodConfig.for_size`) and the
method-specific keys of the recipe set where the method has them. ``sim2real train --preset NAME``,
``sim2real demo --train --preset NAME`` and ``sim2real benchmark --preset NAME`` select them; a
run's ``config.yaml`` reads back as the same config (:func:`load_config`).

=============  =====================================================================================
preset         what it is
=============  =====================================================================================
``paper``      the paper's settings at 256x512 (for a GPU; the default of ``demo --train`` and
               ``benchmark`` there), 3,000 views per scene ray-cast once into the view cache
``small``      the paper's recipe at 128x256 with 32 filters (a quick GPU run)
``tiny``       64x128, 8 filters, 20 iterations (the tests)
``cpu``        the recipe of the shipped model's first stage and the default of ``demo --train`` and
               ``benchmark`` on a CPU: ``small`` with 16 filters, lr 1e-3, edge recall as the
               structure term, view consistency from step 300, a noisy texture start
``cpu-lines``  the shipped model's second stage: ``cpu`` with a drawn line-net texture start and the
               texture's edges weighted 3 (the shipped model's config equals it)
=============  =====================================================================================
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

from sim2real.config import (
    DataConfig,
    DiscriminatorConfig,
    GeneratorConfig,
    LossConfig,
    MethodConfig,
    OptimConfig,
    TrainConfig,
    from_dict,
    override,
    read_yaml,
)
from sim2real.errors import UserError


def _methods():
    # imported here, not at the top: the CLI lists the preset names without loading torch
    import sim2real.methods

    return sim2real.methods


METHOD_PRESETS: dict[str, tuple[str, tuple[str, ...]]] = {
    "ours": ("ours", ()),
    "ours_no_vc": ("ours", ("vc=0",)),
    "ours_l1_vc": ("ours", ("vc_kind=l1",)),
    "ours_no_tex_vc": ("ours", ("texture.features=0", "vc=0")),
    "ssim_munit": ("ssim_munit", ()),
    "recycle": ("recycle", ()),
    "ssim_recycle": ("recycle", ("ssim=true",)),
    "of_unit": ("of_unit", ()),
}
"""Named presets: (method, assignments to its config section)."""


def method_config(name: str, size: str = "paper") -> MethodConfig:
    """The config section of method preset ``name`` at size preset ``size``."""
    if name not in METHOD_PRESETS:
        raise UserError(f"unknown method '{name}' (choose from {', '.join(METHOD_PRESETS)})")
    method, sets = METHOD_PRESETS[name]
    return override(_methods().METHOD_CONFIGS[method].for_size(size), list(sets))


def _with_method(cfg: TrainConfig, method: str, size: str) -> TrainConfig:
    cfg.method = method_config(method, size)
    return cfg


def _method_sets(cfg: TrainConfig, sets: Sequence[str]) -> list[str]:
    """The ``method.*`` assignments of ``sets`` whose key the method's section has (a recipe names
    e.g. ``method.vc_start``, which a method without view consistency does not have)."""
    out = []
    for item in sets:
        target = cfg.method
        *path, last = item.split("=", 1)[0].split(".")[1:]
        for part in path:
            target = getattr(target, part, None)
        if target is not None and dataclasses.is_dataclass(target) and hasattr(target, last):
            out.append(item)
    return out


POOL_VIEWS = 3000
"""``data.view_pool`` of the presets for a GPU: the paper's 3,000 random views per scene
(Section 4), ray-cast once into the view cache (data/viewpool.py). There the loader feeds a step
of milliseconds, and a cached sample costs a worker a third of a fresh one; building the pool
takes about 3,000 x 0.07 s of CPU, 14 s on 16 cores, once per scene (benchmarks/bench_data.py).
Disk: 2.25 MiB a 256x512 view, 6.6 GiB per scene (0.56 MiB and 1.6 GiB at 128x256)."""


def paper(method: str = "ours") -> TrainConfig:
    """The paper's settings (supplementary): 256x512, 64 filters, 3 discriminator scales, MS-SSIM
    with an 11-pixel window, lr 1e-4 / 1e-3, 500k iterations, view consistency from step 10k, and
    the paper's 3,000 views per scene, ray-cast once into the view cache (:data:`POOL_VIEWS`)."""
    cfg = TrainConfig()
    cfg.data = DataConfig(view_pool=POOL_VIEWS)
    return _with_method(cfg, method, "paper")


def small(method: str = "ours") -> TrainConfig:
    """The paper's recipe at 128x256: 32 filters, 2 discriminator scales, a 7-pixel MS-SSIM window
    (pytorch-msssim needs a short side > 16 (win - 1)), 256-texel textures, view consistency from
    step 2000, a view pool of :data:`POOL_VIEWS` per scene."""
    cfg = TrainConfig(iterations=20_000, checkpoint_every=1_000, log_every=50, image_every=500)
    cfg.data = DataConfig(height=128, width=256, view_pool=POOL_VIEWS)
    cfg.generator = GeneratorConfig(filters=32)
    cfg.discriminator = DiscriminatorConfig(filters=32, scales=2)
    cfg.loss = LossConfig(ssim_win=7)
    cfg.optim = OptimConfig(lr_halve_every=10_000)
    return _with_method(cfg, method, "small")


def tiny(method: str = "ours") -> TrainConfig:
    """64x128, 8 filters, one residual block, 20 iterations, loading in the training process: the
    whole path in seconds, for the tests. A 3-pixel MS-SSIM window (the only one at 64 px). A view
    pool of 16 per scene (0.29 MiB of disk): fewer ray casts than the 40 fresh views of its 20
    steps, and the tests run the default data path of the GPU presets."""
    cfg = TrainConfig(iterations=20, checkpoint_every=10, log_every=5, image_every=10)
    cfg.data = DataConfig(height=64, width=128, workers=0, view_pool=16)
    cfg.generator = GeneratorConfig(filters=8, res_blocks=1)
    cfg.discriminator = DiscriminatorConfig(filters=8, layers=2, scales=2)
    cfg.loss = LossConfig(ssim_win=3)
    cfg.optim = OptimConfig(lr_halve_every=1_000)
    return _with_method(cfg, method, "tiny")


CPU_SETS = ("generator.filters=16", "discriminator.filters=16", "optim.lr_net=1e-3", "checkpoint_every=100",
            "image_every=100", "log_every=20", "loss.ab_structure=edges", "loss.edge_power=2", "data.view_pool=0")
CPU_METHOD_SETS = ("method.vc_start=300", "method.tex_edges=1", "method.target_grad=false",
                   "method.texture.init_noise=1.0", "method.texture.init_noise_sigma=1.5")
CPU_LINES_SETS = ("loss.edge_contrast=0.08",)
CPU_LINES_METHOD_SETS = ("method.texture.init_noise=0", "method.texture.init_lines=1",
                         "method.texture.init_lines_sigma=4", "method.tex_edges=3")


def cpu(method: str = "ours") -> TrainConfig:
    """What a 2-core CPU learns most from in minutes to hours (docs/detail_study.md), and the recipe
    of the shipped model's first stage (5162 steps in 139 minutes on one core).

    ``small`` with 16 generator and discriminator filters (about 0.7 s a step on a 2-core CPU), the
    networks' learning rate 10x the paper's (it gave the most consistent matches at 30 CPU minutes),
    edge recall at a_ref's outlines (``loss.edge_power=2``) instead of MS-SSIM as the a -> b
    structure term (the paper's term charges a perfect video more than smooth frames, which a few
    thousand steps do not outweigh), checkpoints every 100 steps. For methods that have them: view
    consistency from step 300; the frames' edge recall at the projected texture's edges
    (``method.tex_edges=1``), the texture learning only through the translator's outputs
    (``method.target_grad=false``) and a start of band-limited noise (``method.texture.init_noise=1``,
    sigma 1.5 texels): detail fixed to the surface from step 0. The noise is a start, not learned
    detail: at this budget the translator learns to render and keep it (white gloss-like flecks).
    Fresh random views (``data.view_pool=0``): a CPU step (0.7 s) hides the loader's 0.03 s of
    ray casting, and a pool of 3,000 would first take about a minute of both cores, a tenth of
    ``demo --train``'s budget, for nothing."""
    cfg = override(small(method), list(CPU_SETS))
    return override(cfg, _method_sets(cfg, CPU_METHOD_SETS))


def cpu_lines(method: str = "ours") -> TrainConfig:
    """The shipped model's second stage: ``cpu`` with a drawn line-net texture start
    (``method.texture.init_noise=0 init_lines=1 init_lines_sigma=4``), the texture's edge recall at
    weight 3 and the edge threshold raised 4x (``loss.edge_contrast=0.08``).

    The line net is a **hand-drawn prior, not learned detail**: dark curves along the zero crossings
    of band-limited noise, drawn into the texture before training. The translator learns to render
    it as vessel-like lines and keep them in place; a CPU budget does not learn vessels of its own.
    Start it from a trained translator (``sim2real train --init-from shipped``), as the shipped model
    was: from scratch the lines are lost before the translator can render them."""
    cfg = override(cpu(method), list(CPU_LINES_SETS))
    return override(cfg, _method_sets(cfg, CPU_LINES_METHOD_SETS))


PRESETS: dict[str, Callable[[str], TrainConfig]] = {
    "paper": paper, "small": small, "tiny": tiny, "cpu": cpu, "cpu-lines": cpu_lines,
}
"""Every named preset (the module docstring says what each is)."""


def preset(name: str, method: str = "ours") -> TrainConfig:
    """Preset ``name`` with method (or method preset, :data:`sim2real.presets.METHOD_PRESETS`) ``method``."""
    if name not in PRESETS:
        raise UserError(f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    return PRESETS[name](method)


def default_preset(cuda: bool) -> str:
    """The preset of ``demo --train`` and ``benchmark`` when none is named: the paper's on a GPU,
    ``cpu`` on a CPU."""
    return "paper" if cuda else "cpu"


def budgeted(name: str, method: str = "ours", device: str = "auto") -> TrainConfig:
    """Preset ``name`` for a run that a wall-clock budget ends (``demo --train``, ``benchmark``): no
    practical bound on the iterations, on ``device``; ``tiny`` checkpoints and logs every 5 steps,
    so that a budget of seconds still leaves a checkpoint and curves."""
    sets = [f"device={device}", f"iterations={UNBOUNDED}"]
    if name == "tiny":
        sets += ["checkpoint_every=5", "image_every=5", "log_every=5"]
    return override(preset(name, method), sets)


UNBOUNDED = 10_000_000
"""The iterations of a budgeted run: the time budget ends it first."""


def config_from_dict(data: dict) -> TrainConfig:
    """A :class:`TrainConfig` from its plain dict (a checkpoint's, a YAML file's); the ``method``
    section is built as the registered class its ``name`` tag names; older layouts migrate."""
    return from_dict(TrainConfig, data, sections=_methods().METHOD_CONFIGS)


def load_config(path) -> TrainConfig:
    """A YAML config file (e.g. a run's ``config.yaml``) as a :class:`TrainConfig`."""
    return config_from_dict(read_yaml(path))
