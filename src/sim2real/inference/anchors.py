"""The ceiling and the floor of an evaluation: two videos of the evaluated views that every metric
is also computed on, so that each figure of a model stands between what this benchmark calls
perfect and what it calls broken.

* **Ceiling**: the stand-in real domain (:mod:`sim2real.realdomain`) rendered on the
  evaluated scene and views with one appearance. Its materials are solid textures, so the video
  is consistent by construction and has the real domain's detail: it is the best video these
  metrics can score here. (When the real folder is the user's own footage, the ceiling still
  describes the stand-in, not their domain; the report says so.)
* **Floor**: the same renderer with a *new appearance every frame* (other vessels, lobules and
  tints), so detail flickers while colours and shading stay realistic.

Cost: building an appearance's solid textures takes a second or two, shading a frame a fraction
of that. So the floor draws from a pool of ``pool`` appearances, frame ``t`` taking appearance
``t mod pool``: with ``pool > orb_max_k`` no two frames that any metric compares (consecutive
frames for OF, frames up to ``orb_max_k`` apart for the ORB curve, and the revisit pairs, which
for these time-independent videos show the forward frames again) share an appearance, which is
all that "a new appearance every frame" means to the metrics.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from sim2real.fileio import read_json_or_none
from sim2real.realdomain import FORMAT, Appearance, RenderOptions, SceneMaterial, derive_seed, render_frame
from sim2real.render.gbuffer import GBuffer

_CEILING, _FLOOR, _NOISE = 31, 32, 33  # seed tags


class Anchors:
    """Ceiling and floor frames of one scene (uint8 RGB, the G-buffer's size)."""

    def __init__(self, scene, seed: int = 0, pool: int = 21, options: RenderOptions | None = None):
        self.scene = scene
        self.seed = int(seed)
        self.pool = max(1, int(pool))
        self.options = options or RenderOptions()
        self._materials: dict[int, SceneMaterial] = {}
        self._lock = threading.Lock()
        self._first: dict[int, threading.Lock] = {}

    def _material(self, key: int) -> SceneMaterial:
        """Key -1: the ceiling's appearance; 0..pool-1: the floor's."""
        with self._lock:
            if key not in self._materials:
                tag = (_CEILING,) if key < 0 else (_FLOOR, key)
                self._materials[key] = SceneMaterial(self.scene, Appearance.sample(derive_seed(self.seed, *tag)))
                self._first[key] = threading.Lock()
            return self._materials[key]

    def _render(self, g: GBuffer, key: int, index: int) -> np.ndarray:
        """Thread-safe: a material's fields are built on its first frames, so a thread rendering an
        appearance for the first time holds that appearance's lock and the others wait for it
        (instead of building the same fields again); the frames are the same in any order."""
        opt = replace(self.options, height=g.height, width=g.width)
        material = self._material(key)
        seed = derive_seed(self.seed, _NOISE, int(index))
        first = self._first.get(key)
        if first is not None:
            with first:
                if key in self._first:
                    image = render_frame(g, material, opt, seed).image
                    del self._first[key]
                    return image
        return render_frame(g, material, opt, seed).image

    def ceiling(self, g: GBuffer, index: int) -> np.ndarray:
        """The stand-in with the ceiling's one appearance; ``index`` seeds the sensor noise."""
        return self._render(g, -1, index)

    def floor(self, g: GBuffer, index: int) -> np.ndarray:
        """The stand-in with appearance ``index mod pool``."""
        return self._render(g, int(index) % self.pool, index)


def stand_in_options(real_root):
    """(RenderOptions, is_stand_in): the camera settings of a stand-in real folder (its
    ``manifest.json``), or the defaults and False for any other folder."""
    for d in (Path(real_root), Path(real_root).parent):
        data = read_json_or_none(d / "manifest.json")
        if data is not None and data.get("format") == FORMAT and isinstance(data.get("render"), dict):
            known = set(RenderOptions.__dataclass_fields__)
            return RenderOptions(**{k: v for k, v in data["render"].items() if k in known}), True
    return RenderOptions(), False
