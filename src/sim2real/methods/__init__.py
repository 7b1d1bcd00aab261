"""Methods as plug-ins: each module registers a :class:`~sim2real.methods.base.Method` and its
config section; named presets of a method (the paper's ablations, :data:`sim2real.presets.METHOD_PRESETS`)
are values of that section.

=================  ==========  ==============================================================
preset             method      what it is
=================  ==========  ==============================================================
``ours``           ours        the paper: neural texture + a_ref, view consistency (angle)
``ours_no_vc``     ours        lambda_vc = 0
``ours_l1_vc``     ours        L1 instead of the angle in L_vc (paper Fig. 7)
``ours_no_tex_vc`` ours        no texture (domain A = a_ref, 3 channels), lambda_vc = 0
``ssim_munit``     ssim_munit  Pfeiffer et al. 2019: MUNIT with styles and input noise + MS-SSIM
``recycle``        recycle     ReCycle-GAN (Bansal et al. 2018) with the non-temporal cycles
``ssim_recycle``   recycle     recycle + the MS-SSIM losses (5 / 3 on grey a_ref <-> b)
``of_unit``        of_unit     E_A fed (w(b_prev), a_ref), b_prev its own output; L1 vc, 50
=================  ==========  ==============================================================
"""

from __future__ import annotations

from sim2real.config import TrainConfig
from sim2real.errors import UserError
from sim2real.methods.base import METHOD_CONFIGS, Method, register_method_config
from sim2real.methods.of_unit import OfUnit
from sim2real.methods.ours import Ours
from sim2real.methods.recycle import Recycle
from sim2real.methods.ssim_munit import SsimMunit

METHODS: dict[str, type[Method]] = {m.name: m for m in (Ours, SsimMunit, Recycle, OfUnit)}
"""Registered methods by name."""


def get_method(cfg: TrainConfig) -> Method:
    """The method object for ``cfg`` (its class is the one registered under the section's name)."""
    name = type(cfg.method).name
    if name not in METHODS:
        raise UserError(f"unknown method '{name}' (choose from {', '.join(METHODS)})")
    return METHODS[name](cfg)


__all__ = ["METHOD_CONFIGS", "METHODS", "Method", "get_method", "register_method_config"]
