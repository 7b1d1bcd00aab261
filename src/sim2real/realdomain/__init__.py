"""A procedural stand-in for real laparoscopic video (domain B of the demo and the benchmark), with
labels. It is a data source, not a renderer of the method: it knows the scene, never the translator.

=====================================  ==========================================================
module                                 holds
=====================================  ==========================================================
:mod:`.appearance`                     per-scene look (:class:`Appearance`), derived seeds, sRGB
:mod:`.solid_texture`                  3-D noise, cell fields and vessel trees on surfaces
:mod:`.materials`                      solid-texture materials per class (:class:`SceneMaterial`)
:mod:`.shading`                        light, camera and sensor (:class:`RenderOptions`,
                                       :func:`render_frame`, :func:`scope_light_falloff`)
:mod:`.writer`                         dataset folders: :func:`make_real_domain`, label PNGs
=====================================  ==========================================================
"""

from sim2real.realdomain.appearance import Appearance, derive_seed, linear_to_srgb, srgb_to_linear
from sim2real.realdomain.materials import (
    MATERIALS,
    SceneMaterial,
    Surface,
    material_fat,
    material_gallbladder,
    material_ligament,
    material_liver,
    material_wall,
)
from sim2real.realdomain.shading import RealFrame, RenderOptions, circular_mask, render_frame, scope_light_falloff
from sim2real.realdomain.writer import FORMAT, make_real_domain, run_jobs, write_label

__all__ = [
    "Appearance", "derive_seed", "linear_to_srgb", "srgb_to_linear",
    "MATERIALS", "SceneMaterial", "Surface", "material_fat", "material_gallbladder", "material_ligament",
    "material_liver", "material_wall",
    "RealFrame", "RenderOptions", "circular_mask", "render_frame", "scope_light_falloff",
    "FORMAT", "make_real_domain", "run_jobs", "write_label",
]
