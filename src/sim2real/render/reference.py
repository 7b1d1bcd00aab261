"""The simple reference rendering a_ref (paper Sec. 3, Eq. 2; authors' constants).

    a_ref = albedo[class] * (0.9 * diffuse + 0.1) * L(d)     (albedo: the class table's a_ref colour)
    diffuse = clamp(n . (-ray direction), 0, 1)          (the light sits on the camera)
    L(d) = 1 / (3.5e-5 d^2 + 4e-4 d + 0.4),   d = min(distance, 100 mm)

``d`` is the Euclidean camera-to-point distance (G-buffer key ``distance``), not the z-depth.
L ranges from 2.5 (d = 0) to 1.27 (d >= 100 mm), so bright, close surfaces exceed 1: the
result is clipped to [0, 1] (a saturated highlight, as a camera sensor would record it).
Background pixels are 0.
"""

from __future__ import annotations

import os

import numpy as np

from sim2real.fileio import atomic_write_image
from sim2real.render.gbuffer import GBuffer
from sim2real.scene.classes import DEFAULT_CLASSES, PAPER_CLASSES, ClassTable

ALBEDO: dict[str, tuple[float, float, float]] = {c: DEFAULT_CLASSES[c].a_ref for c in PAPER_CLASSES}
"""Flat RGB albedo in [0, 1] of the paper's five classes (the authors' constants); other classes
take theirs from the scene's class table (:mod:`sim2real.scene.classes`)."""

FALLOFF = (3.5e-5, 4e-4, 0.4)
DISTANCE_CLAMP_MM = 100.0


def class_albedo(classes: tuple[str, ...] | list[str], table: ClassTable | None = None) -> np.ndarray:
    """(O, 3) albedo of each object, in object-id order (also the neural textures' initial
    colours), from ``table`` (default: the default class table)."""
    return (table if table is not None else ClassTable.defaults()).albedo(classes)


def paper_light_falloff(distance: np.ndarray) -> np.ndarray:
    """The paper's L(d) of a_ref (Eq. 2, authors' constants), ``distance`` Euclidean in mm, clamped
    at 100 mm. Not the stand-in scope's light
    (:func:`sim2real.realdomain.scope_light_falloff`)."""
    d = np.minimum(distance, DISTANCE_CLAMP_MM)
    a, b, c = FALLOFF
    return 1.0 / (a * d * d + b * d + c)


def view_directions(g: GBuffer) -> np.ndarray:
    """Unit world vectors from each surface point towards the camera (H, W, 3); 0 off-surface."""
    to_cam = g.camera.position[None, None].astype(np.float32) - g.points
    n = np.linalg.norm(to_cam, axis=-1, keepdims=True)
    return np.where(g.mask[..., None], to_cam / np.maximum(n, 1e-9), 0).astype(np.float32)


def reference_rendering(g: GBuffer) -> np.ndarray:
    """a_ref of a view as float32 (H, W, 3) RGB in [0, 1]."""
    albedo = np.concatenate([g.class_table.albedo(g.classes), np.zeros((1, 3), np.float32)])[g.object_id]
    diffuse = np.clip(np.einsum("hwc,hwc->hw", g.normal, view_directions(g)), 0.0, 1.0)
    shade = (0.9 * diffuse + 0.1) * paper_light_falloff(g.distance)
    out = albedo * shade[..., None]
    out[~g.mask] = 0.0
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def to_uint8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save_preview(g: GBuffer, path: str | os.PathLike) -> None:
    atomic_write_image(path, to_uint8(reference_rendering(g)))

