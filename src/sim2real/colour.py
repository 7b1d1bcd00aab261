"""Grey values of RGB images: the one luma conversion of the package (ITU-R BT.601,
``Y = 0.299 R + 0.587 G + 0.114 B``, the weights OpenCV's ``COLOR_RGB2GRAY`` uses).

No torch import here: the stand-in renderer (numpy only, also in worker processes) shares the
weights."""

from __future__ import annotations

GREY_WEIGHTS = (0.299, 0.587, 0.114)


def grey(rgb):
    """(B, 3, H, W) RGB -> (B, 1, H, W) grey, in the input's range (no rescaling); a torch tensor
    or a numpy array."""
    if rgb.ndim != 4 or rgb.shape[1] != 3:
        raise ValueError(f"grey: expected (B, 3, H, W), got {tuple(rgb.shape)}")
    r, g, b = GREY_WEIGHTS
    return r * rgb[:, 0:1] + g * rgb[:, 1:2] + b * rgb[:, 2:3]
