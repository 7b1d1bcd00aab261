"""A procedural stand-in for real laparoscopic video (the embedded target domain B), with labels.

The package renders; the dataset writer lives with the other data code:

=====================================  ==========================================================
module                                 holds
=====================================  ==========================================================
:mod:`.appearance`                     per-scene look (:class:`Appearance`), derived seeds, sRGB
:mod:`.materials`                      solid-texture materials per class (:class:`SceneMaterial`)
:mod:`.shading`                        light, camera and sensor (:class:`RenderOptions`,
                                       :func:`render_frame`, :func:`scope_light_falloff`)
:mod:`sim2real.data.realdomain_writer`  dataset folders: :func:`make_real_domain`, label PNGs
=====================================  ==========================================================

Every name that used to live in the single module ``sim2real.render.realdomain`` is still
importable from here; the writer's names are loaded on first use (the writer imports this
package, so importing it eagerly would be circular).
"""

from sim2real.render.realdomain.appearance import Appearance, derive_seed, linear_to_srgb, srgb_to_linear
from sim2real.render.realdomain.materials import (
    MATERIALS, SceneMaterial, Surface, material_fat, material_gallbladder, material_ligament, material_liver,
    material_wall,
)
from sim2real.render.realdomain.shading import (
    RealFrame, RenderOptions, circular_mask, render_frame, scope_light_falloff,
)

light_falloff = scope_light_falloff
"""Old name of :func:`scope_light_falloff` (the stand-in scope's light, not the paper's a_ref
falloff :func:`sim2real.render.reference.paper_light_falloff`); kept for code written before
the split."""

_WRITER_NAMES = ("FORMAT", "make_real_domain", "run_jobs", "write_label")


def __getattr__(name: str):
    if name in _WRITER_NAMES:
        from sim2real.data import realdomain_writer

        return getattr(realdomain_writer, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Appearance", "derive_seed", "linear_to_srgb", "srgb_to_linear",
    "MATERIALS", "SceneMaterial", "Surface", "material_fat", "material_gallbladder", "material_ligament",
    "material_liver", "material_wall",
    "RealFrame", "RenderOptions", "circular_mask", "render_frame", "scope_light_falloff", "light_falloff",
    *_WRITER_NAMES,
]
