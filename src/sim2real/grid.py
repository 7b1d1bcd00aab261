"""Tiling images into one picture (training sample grids, evaluation samples)."""

from __future__ import annotations

import numpy as np


def tile(rows: list[list[np.ndarray]], gap: int = 2) -> np.ndarray:
    """Rows of equally sized uint8 (H, W, 3) images -> one uint8 image with white ``gap``-pixel
    gaps; rows shorter than the longest are padded with white."""
    h, w = rows[0][0].shape[:2]
    cols = max(len(r) for r in rows)
    canvas = np.full((len(rows) * (h + gap) - gap, cols * (w + gap) - gap, 3), 255, np.uint8)
    for r, row in enumerate(rows):
        for c, im in enumerate(row):
            canvas[r * (h + gap): r * (h + gap) + h, c * (w + gap): c * (w + gap) + w] = im
    return canvas
