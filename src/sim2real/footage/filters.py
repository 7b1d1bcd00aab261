"""Frames that would teach the discriminator the wrong thing, and the reasons they are dropped.

- ``dark``: the content's mean grey below 15 of 255 (out of the body, a covered lens);
- ``overexposed``: the content's mean grey above 235, or more than half of it at 250 or more
  (white-out: the lens against tissue, a flash of light);
- ``duplicate``: the perceptual hash (DCT hash of the content, 64 bits, ``imagehash.phash``)
  within ``distance`` bits of a frame kept before (from any source), so that still stretches
  of a video do not weigh many times over;
- ``small_content``: the source's content area below a fraction of its frame (every frame of
  that source).

The hash is ``imagehash``'s (a maintained library on the registry), not a DCT hash of our own.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

REASONS = ("dark", "overexposed", "duplicate", "small_content")
DARK_MEAN = 15.0
BRIGHT_MEAN = 235.0
SATURATED = 250
SATURATED_SHARE = 0.5


def exposure(image: np.ndarray, mask: np.ndarray) -> str | None:
    """'dark', 'overexposed' or None for ``image`` (uint8 RGB) inside ``mask`` (bool)."""
    g = image.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    v = g[mask] if mask.any() else g.ravel()
    m = float(v.mean())
    if m < DARK_MEAN:
        return "dark"
    if m > BRIGHT_MEAN or float((v >= SATURATED).mean()) > SATURATED_SHARE:
        return "overexposed"
    return None


def phash(image: np.ndarray, mask: np.ndarray) -> int:
    """64-bit perceptual hash of ``image`` with the pixels outside ``mask`` black."""
    import imagehash  # imported on use: only ``sim2real realset`` hashes, and imagehash loads PyWavelets

    im = np.where(mask[..., None], image, 0).astype(np.uint8)
    h = imagehash.phash(Image.fromarray(im))
    return int(str(h), 16)


class DuplicateIndex:
    """Hashes of the frames kept so far; a frame within ``distance`` bits of one is a duplicate."""

    def __init__(self, distance: int):
        self.distance = distance
        self._hashes = np.zeros(1024, np.uint64)
        self._n = 0

    def is_duplicate(self, h: int) -> bool:
        if self.distance < 0 or self._n == 0:
            return False
        d = np.bitwise_count(self._hashes[: self._n] ^ np.uint64(h))
        return bool(d.min() <= self.distance)

    def add(self, h: int) -> None:
        if self._n == len(self._hashes):
            self._hashes = np.concatenate([self._hashes, np.zeros_like(self._hashes)])
        self._hashes[self._n] = np.uint64(h)
        self._n += 1
