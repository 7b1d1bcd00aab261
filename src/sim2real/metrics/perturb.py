"""Known defects drawn into frames, for validating realism measures: a measure that ranks well
must score each of these worse than the clean frames (``benchmarks/bench_realism.py``)."""

from __future__ import annotations

import cv2
import numpy as np


def blurred(frame: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """Gaussian blur of ``sigma`` pixels: detail lost."""
    return cv2.GaussianBlur(frame, (0, 0), sigma)


def lined(frame: np.ndarray, rng: np.random.Generator, lines: int = 8, colour=(70, 15, 15)) -> np.ndarray:
    """``lines`` dark winding polylines (5 segments, 1-2 px thick) drawn across the frame: the
    look of drawn vessels that a texture fixed to the surface can bring."""
    h, w = frame.shape[:2]
    out = np.ascontiguousarray(frame.copy())
    for _ in range(lines):
        p = np.array([rng.uniform(0, w), rng.uniform(0, h)])
        d = rng.uniform(-1, 1, 2)
        pts = [p.copy()]
        for _ in range(5):
            d = d + rng.normal(0, 0.5, 2)
            d = d / (np.linalg.norm(d) + 1e-9)
            p = p + d * rng.uniform(0.05, 0.15) * w
            pts.append(p.copy())
        cv2.polylines(out, [np.round(np.array(pts)).astype(np.int32)], False, colour, int(rng.integers(1, 3)),
                      cv2.LINE_AA)
    return out


def specked(frame: np.ndarray, rng: np.random.Generator, density: float = 0.004) -> np.ndarray:
    """Bright 1-2 px specks on ``density`` of the pixels: the flecked look of noise fixed to a
    surface."""
    h, w = frame.shape[:2]
    out = frame.copy()
    n = int(density * h * w)
    ys, xs = rng.integers(0, h, n), rng.integers(0, w, n)
    for y, x in zip(ys, xs):
        s = int(rng.integers(1, 3))
        out[y:y + s, x:x + s] = 245
    return out
