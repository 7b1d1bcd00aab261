"""The look of a stand-in scene: per-scene tissue colours and sizes (:class:`Appearance`), the
seeds every frame derives its own from, and sRGB <-> linear conversions.

Each scene draws a mild variation of tissue colours, vessel density, lobule size and gloss from
its appearance seed (:meth:`Appearance.sample`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np


def derive_seed(seed: int, *keys: int) -> int:
    """An independent 32-bit seed for (seed, keys...): frames get their own seeds, so the output
    does not depend on the number of workers or on the order in which frames are rendered."""
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *[int(k) for k in keys]]).generate_state(1)[0])


def srgb_to_linear(c) -> np.ndarray:
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(c, 1 / 2.4) - 0.055).astype(np.float32)




@dataclass
class Appearance:
    """The look of one scene. Colours are sRGB in [0, 1]; sizes in mm."""

    seed: int = 0
    wall: tuple[float, float, float] = (0.92, 0.62, 0.62)
    wall_milky: tuple[float, float, float] = (0.97, 0.86, 0.80)
    wall_muscle: tuple[float, float, float] = (0.75, 0.38, 0.36)
    artery: tuple[float, float, float] = (0.86, 0.16, 0.12)
    vein: tuple[float, float, float] = (0.66, 0.10, 0.14)
    vessel_density: float = 1.0
    """Multiplies the share of Voronoi edges that carry a vessel."""
    vessel_width: float = 1.0
    liver: tuple[float, float, float] = (0.36, 0.13, 0.13)
    liver_dark: tuple[float, float, float] = (0.24, 0.07, 0.10)
    fat: tuple[float, float, float] = (0.97, 0.71, 0.24)
    fat_deep: tuple[float, float, float] = (0.93, 0.52, 0.15)
    fat_septum: tuple[float, float, float] = (0.85, 0.40, 0.16)
    lobule_mm: float = 9.0
    gallbladder: tuple[float, float, float] = (0.42, 0.48, 0.24)
    ligament: tuple[float, float, float] = (0.82, 0.68, 0.64)
    gloss: float = 1.0
    light_reference_mm: float = 70.0
    """Distance at which the light's falloff equals 1."""
    exposure: float = 1.0

    @classmethod
    def sample(cls, seed: int) -> "Appearance":
        """Mild per-scene variation around the defaults (same seed, same look)."""
        rng = np.random.default_rng(derive_seed(seed, 1))
        base = cls(seed=int(seed))

        def tint(c, brightness=0.05, hue=0.03):
            c = np.asarray(c) * (1.0 + rng.normal(0.0, brightness))
            c = c * (1.0 + rng.normal(0.0, hue, size=3))
            return tuple(float(x) for x in np.clip(c, 0.02, 0.98))

        values = {
            "seed": int(seed),
            "vessel_density": float(rng.uniform(0.7, 1.3)),
            "vessel_width": float(rng.uniform(0.8, 1.25)),
            "lobule_mm": float(rng.uniform(7.0, 12.0)),
            "gloss": float(rng.uniform(0.75, 1.25)),
            "light_reference_mm": float(rng.uniform(60.0, 80.0)),
            "exposure": float(rng.uniform(0.92, 1.08)),
        }
        for f in fields(cls):
            if f.name not in values:
                values[f.name] = tint(getattr(base, f.name))
        return cls(**values)

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}
