"""The embedded defaults' data: procedural simulated scenes and the stand-in real domain, made on
the spot (``sim2real demo`` and ``sim2real benchmark`` without data flags)."""

from __future__ import annotations

from pathlib import Path

from sim2real.realdomain.writer import make_real_domain
from sim2real.scene.procedural import generate_scene

REAL_SEED_OFFSET = 1000
"""Real-domain scenes use seeds S + 1000, ...: never the simulated scenes' seeds."""


def make_embedded_data(out: Path, seed: int, scenes: int, real_images: int, height: int, width: int,
                       sequences: int = 0, sequence_frames: int = 30, say=print,
                       check=None) -> tuple[list[Path], Path]:
    """``scenes`` simulated scenes (seeds ``seed``, ``seed + 1``, ...) under ``out/scenes/sim_K`` and
    a stand-in real domain of ``real_images`` labelled frames (and ``sequences`` sequences of
    ``sequence_frames`` frames, for the video methods) under ``out/real``, rendered from two scenes
    of other seeds (the domains are unpaired). Returns (simulated scene folders, real folder).
    ``check(scenes)`` sees the simulated scenes before anything is written (it may raise)."""
    say(f"simulated scenes ({scenes})")
    sim = [generate_scene(seed + k) for k in range(scenes)]
    if check is not None:
        check(sim)
    sim_dirs = [Path(s.save(out / "scenes" / f"sim_{k}")) for k, s in enumerate(sim)]
    say("stand-in real domain" + (f" with {sequences} sequences" if sequences else ""))
    real_dirs = [generate_scene(seed + REAL_SEED_OFFSET + k).save(out / "scenes" / f"real_{k}") for k in range(2)]
    make_real_domain(real_dirs, out / "real", images=real_images, sequences=sequences, frames=sequence_frames,
                     height=height, width=width, seed=seed)
    return sim_dirs, out / "real"
