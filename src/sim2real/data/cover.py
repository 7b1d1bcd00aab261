"""The one cover-resize of real images: scale an image so that it covers ``height x width``
(aspect kept), optionally by a further factor, and cut a ``height x width`` window.

Only the window is resampled (PIL ``resize`` with a source ``box``): the result equals resizing
the whole image and then cropping (within a grey level of rounding), at a fraction of the cost
for large frames. Training draws random windows (:func:`random_cover_crops`, the paper's random
resized crop), the evaluation takes the centre one (:func:`fit_image`).

A real set with a content mask (the endoscope's field of view less its overlays,
``sim2real realset``) passes ``valid``: then the factor is relative to the largest window of the
crop's aspect that fits inside the mask (:func:`inscribed_scale`), and the window is drawn among
the positions where it, and the bilinear filter's reach around it, lies wholly inside the mask,
so that no crop ever holds a masked pixel.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

from sim2real.errors import UserError


def resize_box(image: np.ndarray, box: tuple[float, float, float, float], height: int, width: int,
               nearest: bool = False) -> np.ndarray:
    """The source region ``box`` = (left, top, right, bottom) of ``image`` resampled to
    ``height x width`` (bilinear, area-filtered when shrinking; nearest for labels)."""
    resample = Image.NEAREST if nearest else Image.BILINEAR
    return np.asarray(Image.fromarray(image).resize((width, height), resample, box=box))


def _cover_size(h: int, w: int, height: int, width: int, factor: float) -> tuple[int, int]:
    f = max(height / h, width / w) * factor
    return max(height, round(h * f)), max(width, round(w * f))


def cover_window(image: np.ndarray, height: int, width: int, factor: float, top: int, left: int,
                 nearest: bool = False) -> np.ndarray:
    """The ``height x width`` window at (``top``, ``left``) of ``image`` scaled to cover
    ``height x width`` times ``factor`` (the scaled size is rounded to whole pixels)."""
    h, w = image.shape[:2]
    nh, nw = _cover_size(h, w, height, width, factor)
    if (nh, nw) == (h, w):
        return np.ascontiguousarray(image[top:top + height, left:left + width])
    sy, sx = h / nh, w / nw
    return resize_box(image, (left * sx, top * sy, (left + width) * sx, (top + height) * sy), height, width, nearest)


def fit_image(image: np.ndarray, height: int, width: int, nearest: bool = False) -> np.ndarray:
    """Resize so that ``image`` covers ``height x width`` (aspect kept), then crop the centre."""
    h, w = image.shape[:2]
    if (h, w) == (height, width):
        return image
    nh, nw = _cover_size(h, w, height, width, 1.0)
    return cover_window(image, height, width, 1.0, (nh - height) // 2, (nw - width) // 2, nearest)


def random_cover_crops(images: list[np.ndarray], height: int, width: int, scale_min: float, scale_max: float,
                       rng: np.random.Generator, valid: "ValidArea | None" = None) -> list[np.ndarray]:
    """One random window for all ``images`` (frames of one size that must stay aligned): the
    images scaled by ``max(height / h, width / w) * U[scale_min, scale_max]`` and cut at a random
    position. With ``valid`` the factor is relative to the largest window inside the mask and
    the window lies inside it (module docstring); a factor below 1 is raised to 1 there (it would
    need pixels outside the mask)."""
    h, w = images[0].shape[:2]
    if any(im.shape[:2] != (h, w) for im in images):
        raise UserError(f"frames of one sequence differ in size: {sorted({im.shape[:2] for im in images})}")
    u = float(rng.uniform(scale_min, scale_max))
    if valid is None:
        nh, nw = _cover_size(h, w, height, width, u)
        top = int(rng.integers(0, nh - height + 1))
        left = int(rng.integers(0, nw - width + 1))
        return [cover_window(im, height, width, u, top, left) for im in images]
    if valid.shape != (h, w):
        raise UserError(f"content mask is {valid.shape[0]}x{valid.shape[1]} but its image is {h}x{w}")
    box = valid.draw(height, width, max(u, 1.0), rng)
    return [resize_box(im, box, height, width) for im in images]


class ValidArea:
    """Where crops may come from: a boolean mask (True = content), its integral image, and the
    largest window of each crop aspect that fits inside (cached)."""

    def __init__(self, mask: np.ndarray):
        self.mask = np.asarray(mask, dtype=bool)
        if not self.mask.any():
            raise UserError("content mask is empty")
        self.shape = self.mask.shape
        bad = (~self.mask).astype(np.int32)
        self._sum = np.pad(bad.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
        self._inscribed: dict[tuple[int, int], float] = {}

    def _fits(self, wh: int, ww: int) -> np.ndarray:
        """Boolean (H - wh + 1, W - ww + 1): windows of wh x ww pixels at each top-left that hold
        no masked pixel."""
        H, W = self.shape
        if wh > H or ww > W or wh < 1 or ww < 1:
            return np.zeros((0, 0), bool)
        s = self._sum
        bad = s[wh:, ww:] - s[:-wh, ww:] - s[wh:, :-ww] + s[:-wh, :-ww]
        return bad == 0

    @staticmethod
    def _reach(k: float) -> int:
        """Source pixels beyond a box that PIL's bilinear filter reads for a box k source pixels
        per output pixel: one when enlarging, k (rounded up) when shrinking."""
        return max(1, math.ceil(k))

    def _extent(self, k: float, height: int, width: int) -> tuple[int, int]:
        r = self._reach(k)
        return math.ceil(k * height) + 2 * r, math.ceil(k * width) + 2 * r

    def inscribed_scale(self, height: int, width: int) -> float:
        """The largest k with a window of ``k*height x k*width`` source pixels and the filter's
        reach around it inside the mask; bisection on k."""
        key = (height, width)
        if key not in self._inscribed:
            lo, hi = 0.0, min(self.shape[0] / height, self.shape[1] / width)
            for _ in range(30):
                k = (lo + hi) / 2
                if self._fits(*self._extent(k, height, width)).any():
                    lo = k
                else:
                    hi = k
            if lo * min(height, width) < 1:
                raise UserError(f"the content mask holds no window of the crop's aspect {width}:{height}")
            self._inscribed[key] = lo
        return self._inscribed[key]

    def draw(self, height: int, width: int, factor: float,
             rng: np.random.Generator) -> tuple[float, float, float, float]:
        """A random source box (left, top, right, bottom) of the crop's aspect, ``factor`` (>= 1)
        times smaller than the largest inscribed one, whose pixels and bilinear reach (1 source
        pixel when enlarging, the shrink factor when reducing) are all inside the mask."""
        k = self.inscribed_scale(height, width) / factor
        bh, bw = k * height, k * width
        reach = self._reach(k)
        ys, xs = np.nonzero(self._fits(*self._extent(k, height, width)))
        i = int(rng.integers(0, len(ys)))  # not empty: a smaller window than the inscribed one fits
        top, left = ys[i] + reach, xs[i] + reach
        return (float(left), float(top), left + bw, top + bh)
