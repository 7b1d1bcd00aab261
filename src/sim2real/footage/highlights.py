"""Specular highlights in real frames: found and painted out (``sim2real realset --highlights
inpaint``).

In laparoscopy the light leaves at the lens, so a highlight sits where a wet surface faces the
camera and moves with every camera motion. A neural texture is fixed to the surface: trained
against frames with highlights, it paints highlights onto the tissue, where they stay put (see
docs/own-data.md). Removing them from the real frames takes that target away.

**Found** (thresholds on HSV, after Arnold et al. 2010, "Automatic segmentation and inpainting of
specular highlights for endoscopic imaging"): a pixel is a highlight where it is

- *brighter than its surroundings*: its value (HSV V, 0-255) at least :data:`RELATIVE` above the
  median value of a window 1/16 of the frame's short side, itself at least :data:`VALUE_MIN`,
  and nearly white (saturation at most :data:`SATURATION_MAX`); a uniformly pale organ (a
  gallbladder, fat) is not brighter than its surroundings and stays;
- or *clipped*: value at least :data:`CLIPPED_VALUE` and saturation at most
  :data:`CLIPPED_SATURATION`.

The set is grown by 1/128 of the short side (the halo around a highlight) and kept inside the
content mask, eroded by half the median window (where the window would see the black surround).
A connected region larger than :data:`LARGEST` of the content is left as it is. On 30 Cholec
frames, 6 regions were larger (2.1-15.7 % each): five an instrument's metal shaft or an
overexposed area at the rim of the view, one a large reflection on wet tissue, which therefore
stays; below it were reflections on tissue and on instrument edges (a frame's largest region:
median 1.2 %). Inpainting a region that large smears tissue colour over an instrument, or leaves
a hard white edge where the region meets the rim.

**Painted out** with OpenCV's inpainting (Telea's fast marching method, ``cv2.INPAINT_TELEA``),
radius 1/100 of the short side: smooth colour from the border of each highlight inwards.
Texture inside a large highlight is not recovered, and so a frame with large highlights turns
smoother there.
"""

from __future__ import annotations

import cv2
import numpy as np

MODES = ("keep", "inpaint")
RELATIVE = 30
VALUE_MIN = 180
SATURATION_MAX = 90
CLIPPED_VALUE = 250
CLIPPED_SATURATION = 40
LARGEST = 0.02


def _odd(n: float) -> int:
    return max(3, int(n) | 1)


def highlight_mask(rgb: np.ndarray, content: np.ndarray) -> np.ndarray:
    """Bool (H, W): the specular highlights of uint8 RGB ``rgb`` inside bool ``content`` (see the
    module docstring)."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    s, v = hsv[..., 1].astype(np.int16), hsv[..., 2]
    short = min(rgb.shape[:2])
    window = _odd(short / 16)
    local = cv2.medianBlur(v, window).astype(np.int16)
    v = v.astype(np.int16)
    brighter = (v - local >= RELATIVE) & (v >= VALUE_MIN) & (s <= SATURATION_MAX)
    clipped = (v >= CLIPPED_VALUE) & (s <= CLIPPED_SATURATION)
    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_odd(short / 64),) * 2)
    found = cv2.dilate((brighter | clipped).astype(np.uint8), grow) > 0
    inside = cv2.erode(content.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_RECT, (window, window))) > 0
    found &= inside
    _, regions, stats, _ = cv2.connectedComponentsWithStats(found.astype(np.uint8), connectivity=8)
    # region 0 is the rest of the frame
    large = 1 + np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] > LARGEST * max(int(content.sum()), 1))
    if large.size:
        found &= ~np.isin(regions, large)
    return found


def inpaint_highlights(rgb: np.ndarray, content: np.ndarray) -> tuple[np.ndarray, float]:
    """``rgb`` with its highlights painted out, and the fraction of the content they covered."""
    mask = highlight_mask(rgb, content)
    share = float(mask.sum()) / max(int(content.sum()), 1)
    if not mask.any():
        return rgb, 0.0
    radius = max(3, round(min(rgb.shape[:2]) / 100))
    return cv2.inpaint(np.ascontiguousarray(rgb), mask.astype(np.uint8), radius, cv2.INPAINT_TELEA), share
