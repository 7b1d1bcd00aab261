"""Checks of a whole training configuration: every field's domain and the sizes that depend on
each other across sections (image size, generator and discriminator depth, MS-SSIM window).

It imports the modules that define those limits (losses, models, camera, the method registry),
which is why it is not part of the leaf :mod:`sim2real.config`.
"""

from __future__ import annotations

import math
from typing import Any

from sim2real.config import TrainConfig
from sim2real.errors import UserError
from sim2real.losses.ssim import MS_SSIM_WEIGHTS, check_ssim_size
from sim2real.losses.structure import STRUCTURES
from sim2real.methods import METHOD_CONFIGS
from sim2real.models.discriminator import min_input_side as dis_min_side
from sim2real.models.layers import NORMS, PADS
from sim2real.models.translator import min_input_side as gen_min_side
from sim2real.scene.camera import FOV_RANGE_DEG, check_size, view_intrinsics


def validate(cfg: TrainConfig) -> None:
    """Refuse a configuration whose values would fail later, or silently do something else.

    Checks every field's domain (the ``method`` section checks its own,
    :meth:`MethodConfig.check`), then the sizes that depend on each other (image
    size vs the generator's downsamplings, the discriminator's depth and the MS-SSIM window).
    Raises a :class:`UserError` naming the offending key.
    """
    def need(ok: bool, key: str, what: str, value: Any) -> None:
        if not ok:
            raise UserError(f"config key '{key}' must be {what}, got {value!r}")

    def at_least(section: Any, prefix: str, names: str, low: int) -> None:
        for name in names.split():
            v = getattr(section, name)
            need(v >= low, prefix + name, f">= {low}", v)

    def choice(value: str, key: str, options) -> None:
        need(value in options, key, "one of " + ", ".join(options), value)

    choice(cfg.device, "device", ("auto", "cpu", "cuda"))
    at_least(cfg, "", "iterations checkpoint_every log_every image_every", 1)
    at_least(cfg, "", "seed", 0)

    g, d, L, o, dat = cfg.generator, cfg.discriminator, cfg.loss, cfg.optim, cfg.data
    at_least(g, "generator.", "filters", 1)
    at_least(g, "generator.", "downsamplings res_blocks content_channels", 0)
    choice(g.upsample_norm, "generator.upsample_norm", NORMS)
    choice(g.pad_type, "generator.pad_type", tuple(PADS))
    at_least(d, "discriminator.", "filters layers scales", 1)
    choice(d.norm, "discriminator.norm", NORMS)
    choice(d.pad_type, "discriminator.pad_type", tuple(PADS))
    for name in ("adv", "cyc", "rec", "content", "ssim_ab", "ssim_ba"):
        v = getattr(L, name)
        need(math.isfinite(v) and v >= 0, f"loss.{name}", "a finite weight >= 0", v)
    choice(L.ab_structure, "loss.ab_structure", STRUCTURES)
    need(math.isfinite(L.edge_contrast) and L.edge_contrast > 0, "loss.edge_contrast", "finite and > 0", L.edge_contrast)
    need(math.isfinite(L.edge_sigma) and L.edge_sigma >= 0, "loss.edge_sigma", "finite and >= 0", L.edge_sigma)
    need(math.isfinite(L.edge_power) and L.edge_power > 0, "loss.edge_power", "finite and > 0", L.edge_power)
    need(1 <= L.ssim_scales <= len(MS_SSIM_WEIGHTS), "loss.ssim_scales", f"in 1..{len(MS_SSIM_WEIGHTS)}", L.ssim_scales)
    for name in ("lr_net", "lr_tex"):
        v = getattr(o, name)
        need(math.isfinite(v) and v > 0, f"optim.{name}", "a finite learning rate > 0", v)
    for name in ("beta1", "beta2"):
        v = getattr(o, name)
        need(0 <= v < 1, f"optim.{name}", "in [0, 1)", v)
    need(math.isfinite(o.weight_decay) and o.weight_decay >= 0, "optim.weight_decay", "finite and >= 0", o.weight_decay)
    at_least(o, "optim.", "lr_halve_every", 1)
    need(math.isfinite(dat.real_scale_max) and 0 < dat.real_scale_min <= dat.real_scale_max, "data.real_scale_min",
         f"> 0 and <= data.real_scale_max ({dat.real_scale_max})", dat.real_scale_min)
    at_least(dat, "data.", "workers", -1)
    need(math.isfinite(dat.path_step_mm) and dat.path_step_mm >= 0, "data.path_step_mm", "finite and >= 0",
         dat.path_step_mm)
    need(0 <= dat.min_overlap <= 1, "data.min_overlap", "a fraction in [0, 1]", dat.min_overlap)
    need(dat.view_pool == 0 or dat.view_pool >= 2, "data.view_pool",
         "0 (fresh random views) or at least 2 (view pairs need two views)", dat.view_pool)
    lo, hi = FOV_RANGE_DEG
    need(lo <= dat.fov_x_deg <= hi, "data.fov_x_deg", f"in [{lo:g}, {hi:g}] degrees", dat.fov_x_deg)
    check_size(dat.height, dat.width)
    if dat.intrinsics is not None:
        try:
            view_intrinsics(dat.width, dat.height, dat.fov_x_deg, dat.intrinsics)
        except UserError as e:
            raise UserError(f"data.intrinsics (pixels of {dat.height}x{dat.width}): {e}") from None
    if type(cfg.method).name not in METHOD_CONFIGS:
        raise UserError(f"unknown method '{type(cfg.method).name}'")
    cfg.method.check(cfg, need)

    step = 2**g.downsamplings
    if dat.height % step or dat.width % step:
        raise UserError(f"data.height and data.width must be multiples of {step} (2**generator.downsamplings), "
                        f"got {dat.height}x{dat.width}")
    short = min(dat.height, dat.width)
    for side, what in ((gen_min_side(g), f"generator.downsamplings={g.downsamplings}"),
                       (dis_min_side(d), f"discriminator.scales={d.scales} with discriminator.layers={d.layers}")):
        if short < side:
            raise UserError(f"{what} needs images of at least {side} px on the short side, "
                            f"got {dat.height}x{dat.width} (data.height x data.width)")
    if L.ssim_ab or L.ssim_ba:
        try:
            check_ssim_size(dat.height, dat.width, L.ssim_win)
        except ValueError as e:
            raise UserError(str(e)) from None
