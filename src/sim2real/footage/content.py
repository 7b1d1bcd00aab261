"""The content area of a source: the endoscope's field of view less its fixed overlays.

Method (per source, from the temporal mean and standard deviation of its sampled frames' grey
values at an analysis size whose long side is at most 640 px):

1. **Dark surround.** Pixels that are dark on average (mean < 20 of 255) and do not change
   (std < 8) and that connect to the frame's border are the surround: the black corners of a
   circular view, the black side areas of a rectangular one, a black bar with its frame.
2. **Field of view.** The largest connected region of the rest, and its convex hull (a circle,
   a circle clipped by the frame, a rectangle: the views an endoscope makes are convex), so
   that dark tissue at the view's rim does not bite into it. The hull's polygon is drawn at the
   frame's full size, then eroded by 0.4 % of the short side (at least 2 px) to leave out the
   rim's soft fall-off.
3. **Overlays.** Where the frames change (the median std inside the view is at least 4),
   pixels inside the view that stay still (std below a tenth of that median, and below 2.5) form
   the overlays: OSD bars, text, logos. Only regions of at least 0.05 % of the frame count, and
   only those with sharp edges in the mean image (a tenth of their pixels, widened by 2 px, with
   a grey gradient of 20 per pixel or more: text and graphics, not still tissue under a fixed
   camera); they are dilated by 1 % of the short side (text's anti-aliased rims, compression).
   When more than a third of the view is still, the scene itself is taken to be still (a fixed
   camera) and no overlay is masked.
4. **Edge bars.** Along each edge of the view, spans of at least 10 % of the frame where, from
   the edge inwards (after up to 1 % of other lines: a bright frame line), pixels are dark on
   average (mean < 45) or still (std below 0.35 of the view's median) for 2 px or more and stop
   before 6 % of the frame, are bars (OSD bars whose text or frame jitters from frame to frame,
   as in robotic console recordings); they are masked. Both this and step 3 need
   three or more frames.
5. **Box.** The bounding box of what remains; rows or columns at its edges that are more than
   half overlay (a bar across the view) are cut off.
6. **Frames whose view differs.** Each frame's own field of view (steps 1 and 2 on the frame
   alone) is compared with the source's; where their intersection over union is below 0.8, or
   below 0.95 while the frame's view reaches 1 % of the frame beyond the source's (a zoom, a
   scope change, a view that moves), the frame gets its own mask and box: its view less the
   source's overlays. A view that shrinks by less is taken for dark tissue at the rim.

A maintained detector was looked for: ``torchcontentarea`` (0.4.0, 2022, MIT) fits a circle to
the view's edge. It is not used: its only distributions are wheels for CPython 3.8/3.9 holding
compiled extensions for torch 1.9-1.12 with CUDA 10.2-11.6 (no source distribution; its
repository builds a CUDA extension, and its pure-Python module only raises NotImplementedError),
so it cannot be installed beside this project's torch 2.13 on Python 3.10+, and could not be
measured here. It would also find only circles: not the rectangular views with black sides, nor
overlays. On the user's own footage this detector found (docs/footage.md): the circular view of
a CholecSeg8k clip, the clipped circle of Cholec80 frames, and the OSD bar of robotic frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from sim2real.errors import UserError

ANALYSIS_LONG_SIDE = 640
DARK_MEAN = 20.0
DARK_STD = 8.0
MOTION_STD = 4.0
STILL_RATIO = 0.1
STILL_MAX = 2.5
OVERLAY_MIN_AREA = 0.0005
STILL_SCENE = 1 / 3
MOVED_IOU = 0.8
GROWN_IOU = 0.95
GROWN_SHARE = 0.01
BAR_DARK = 45.0
BAR_STILL = 0.35
BAR_LENGTH = 0.1
BAR_DEPTH = 0.06
BAR_EDGE_LINES = 0.01
OVERLAY_EDGE = 20.0


def analysis_size(h: int, w: int) -> tuple[int, int]:
    s = min(1.0, ANALYSIS_LONG_SIDE / max(h, w))
    return max(1, round(h * s)), max(1, round(w * s))


def grey(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """uint8 RGB -> float64 grey at the analysis ``size`` (h, w), area-averaged."""
    if image.shape[:2] != size:
        image = cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float64)


class FrameStats:
    """Running per-pixel mean and variance (Welford) of a source's frames at the analysis size."""

    def __init__(self):
        self.n, self.mean, self.m2, self.frame_size, self.size = 0, None, None, None, None

    def add(self, image: np.ndarray) -> None:
        if self.frame_size is None:
            self.frame_size = image.shape[:2]
            self.size = analysis_size(*self.frame_size)
            self.mean = np.zeros(self.size)
            self.m2 = np.zeros(self.size)
        elif image.shape[:2] != self.frame_size:
            raise UserError(f"frames of one source differ in size ({self.frame_size} and {image.shape[:2]})")
        g = grey(image, self.size)
        self.n += 1
        d = g - self.mean
        self.mean += d / self.n
        self.m2 += d * (g - self.mean)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self.m2 / max(1, self.n - 1))


@dataclass
class ContentArea:
    mask: np.ndarray
    """bool (H, W) at the frame's size, True = content."""
    box: tuple[int, int, int, int]
    """(top, left, bottom, right), bottom/right exclusive."""
    shape: str
    """'full' (no surround found), 'circle'-like or 'rectangle'-like view, from the hull's fill."""
    overlay_fraction: float
    """Share of the frame masked as overlay."""
    overlay: np.ndarray | None = None
    """bool (H, W): the overlays masked (still regions, edge bars)."""
    view_small: np.ndarray | None = None
    """bool (h, w): the field of view (convex hull) at the analysis size, to compare frames with."""

    @property
    def fraction(self) -> float:
        return float(self.mask.mean())

    def crop(self, a: np.ndarray) -> np.ndarray:
        t, l, b, r = self.box
        return a[t:b, l:r]


def _components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return n, lab, stats


def _view(mean: np.ndarray, std: np.ndarray):
    """Steps 1 and 2 (module docstring) at the analysis size: (surround, region, hull points or
    None where no surround was found, the view); None where nothing but surround is found."""
    h, w = mean.shape
    dark = (mean < DARK_MEAN) & (std < DARK_STD)
    n, lab, _ = _components(dark)
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    surround = np.isin(lab, border[border > 0]) & dark
    n, lab, st = _components(~surround)
    if n <= 1:
        return None
    region = lab == 1 + int(np.argmax(st[1:, cv2.CC_STAT_AREA]))
    if not surround.any():
        return surround, region, None, np.ones((h, w), bool)
    # the hull of the region's outer contour (the same as of all its pixels, 10x faster)
    contours, _ = cv2.findContours(region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    hull = cv2.convexHull(np.concatenate(contours)).reshape(-1, 2).astype(np.float64)
    view_small = np.zeros((h, w), np.uint8)
    cv2.fillPoly(view_small, [hull.astype(np.int32)], 1)
    return surround, region, hull, view_small.astype(bool)


def _full_view(hull: np.ndarray | None, small: tuple[int, int], full: tuple[int, int]) -> tuple[np.ndarray, str] | None:
    """The view of step 2 drawn at the ``full`` frame size from its hull at the ``small`` size,
    eroded for the rim, and its shape; None when nothing is left."""
    H, W = full
    h, w = small
    if hull is None:
        return np.ones((H, W), bool), "full"
    # pixel centres at analysis scale -> full scale; the hull of pixel centres is half a pixel
    # inside the region's outline on each side, so it is pushed out by that half pixel
    hull = hull + 0.5 * np.sign(hull - hull.mean(axis=0))
    hull_full = np.round((hull + 0.5) * [W / w, H / h] - 0.5).astype(np.int32)
    view = np.zeros((H, W), np.uint8)
    cv2.fillPoly(view, [hull_full], 1)
    r = max(2, round(0.004 * min(H, W)))
    view = cv2.erode(view, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))).astype(bool)
    ys, xs = np.nonzero(view)
    if not len(ys):
        return None
    fill = view.sum() / ((ys.max() - ys.min() + 1) * (xs.max() - xs.min() + 1))
    return view, "rectangle" if fill > 0.99 else "circle"


def detect(stats: FrameStats) -> ContentArea:
    """The content area of a source from its frame statistics (module docstring)."""
    H, W = stats.frame_size
    h, w = stats.size
    mean, std = stats.mean, stats.std
    short = min(H, W)
    found = _view(mean, std)
    drawn = _full_view(found[2], (h, w), (H, W)) if found is not None else None
    if drawn is None:
        return ContentArea(np.zeros((H, W), bool), (0, 0, 0, 0), "empty", 0.0)
    surround, region, _, view_small = found
    view, shape = drawn
    # 3. still overlays inside the view (only where the rest moves)
    overlay = np.zeros((H, W), bool)
    inside = region & ~surround
    if stats.n >= 3 and inside.any():
        moving = float(np.median(std[inside]))
        if moving >= MOTION_STD:
            still = inside & (std < min(STILL_MAX, STILL_RATIO * moving))
            still = cv2.morphologyEx(still.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
            n, lab, st = _components(still)
            keep = np.zeros(n, bool)
            keep[1:] = st[1:, cv2.CC_STAT_AREA] >= OVERLAY_MIN_AREA * h * w
            gy, gx = np.gradient(mean)
            edges = cv2.dilate(np.hypot(gx, gy).astype(np.float32), np.ones((5, 5), np.uint8))
            for c in np.nonzero(keep)[0]:  # graphics have sharp edges; still tissue (a fixed camera) has not
                keep[c] = np.percentile(edges[lab == c], 90) >= OVERLAY_EDGE
            small = keep[lab]
            if small.sum() <= STILL_SCENE * inside.sum():
                big = cv2.resize(small.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST)
                r = max(2, round(0.01 * short))
                disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
                overlay = cv2.dilate(big, disk).astype(bool)
    if stats.n >= 3 and inside.any():
        band = _edge_bands(mean, std, inside, float(np.median(std[inside])))
        if band.any():
            overlay |= cv2.resize(band.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)
    return _area(view, overlay, shape, view_small)


def _area(view: np.ndarray, overlay: np.ndarray, shape: str, view_small) -> ContentArea:
    """The content area of a field of view less its overlays, trimmed to its box."""
    mask = view & ~overlay
    box = _box(mask, overlay & view)
    t, l, b, r = box
    trimmed = np.zeros_like(mask)
    trimmed[t:b, l:r] = mask[t:b, l:r]
    return ContentArea(trimmed, box, shape, float((overlay & view).mean()), overlay & view, view_small)


def frame_area(image: np.ndarray, source: ContentArea, size: tuple[int, int]) -> ContentArea | None:
    """The content area of one frame whose field of view differs from its source's (a zoom, a
    scope change, a view that moves), else None. It differs when the two views at the analysis
    ``size`` overlap with an intersection over union below 0.8, or below 0.95 while the frame's
    view reaches beyond the source's by 1 % of the frame or more (a view that only shrinks a
    little is most often dark tissue at the rim, not a new view). Then the frame's own view
    (steps 1, 2 and 5 on the frame alone) less the source's overlays is its content area."""
    if source.view_small is None:
        return None
    g = grey(image, size)
    found = _view(g, np.zeros_like(g))
    if found is None:
        return None
    _, _, hull, view_small = found
    inter = float((view_small & source.view_small).sum())
    union = float((view_small | source.view_small).sum())
    grown = float((view_small & ~source.view_small).mean())
    if union == 0 or not (inter / union < MOVED_IOU or (inter / union < GROWN_IOU and grown >= GROWN_SHARE)):
        return None
    drawn = _full_view(hull, size, image.shape[:2])
    if drawn is None:
        return None
    view, shape = drawn
    overlay = source.overlay if source.overlay is not None else np.zeros_like(view)
    return _area(view, overlay, shape, view_small)


def _edge_bands(mean: np.ndarray, std: np.ndarray, inside: np.ndarray, moving: float) -> np.ndarray:
    """Bars along the view's edges (analysis size). Per column (for the top and bottom edges; per
    row for the sides): the run of overlay-like pixels (dark on average, mean < 45, or still, std
    below 0.35 of the view's median) from the edge of the view's box inwards, after at most 1 %
    of the frame of other lines (a bright frame line). Columns whose run is 2 px or more and ends
    before 6 % of the frame (a bar has an inner edge; dark tissue runs on) form spans; spans of at
    least 10 % of the frame's width are bars, masked to their deepest run. Catches OSD bars whose
    text or frame jitters too much for the still test."""
    like = inside & ((mean < BAR_DARK) | (std < BAR_STILL * moving))
    band = np.zeros(inside.shape, bool)
    ys, xs = np.nonzero(inside)
    t, b, l, r = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    views = ((like[t:b, l:r], band[t:b, l:r]), (like[t:b, l:r][::-1], band[t:b, l:r][::-1]),
             (like[t:b, l:r].T, band[t:b, l:r].T), (like[t:b, l:r].T[::-1], band[t:b, l:r].T[::-1]))
    for lk, bd in views:  # lk: rows from the edge inwards; bd: the band's view of the same pixels
        depth = max(3, round(BAR_DEPTH * lk.shape[0]))
        skip = max(1, round(BAR_EDGE_LINES * lk.shape[0]))
        strip = lk[:depth + 1]
        first = np.argmax(strip[:skip + 1], axis=0)  # first like row within the skip lines
        has = strip[:skip + 1].any(axis=0)
        run = np.zeros(lk.shape[1], int)
        for j in np.nonzero(has)[0]:
            col = strip[first[j]:, j]
            run[j] = first[j] + (int(np.argmin(col)) if not col.all() else len(col))
        bar = (run - first >= 2) & (run < depth) & has
        bar = np.convolve(bar.astype(float), np.ones(5), "same") > 0  # bridge gaps of a few columns
        bar &= has
        n, lab = cv2.connectedComponents(bar.astype(np.uint8)[None, :], connectivity=4)
        for c in range(1, n):
            cols = np.nonzero(lab[0] == c)[0]
            if len(cols) >= BAR_LENGTH * lk.shape[1]:
                bd[: int(np.percentile(run[cols], 90)), cols[0]:cols[-1] + 1] = True
    return band & inside


def _box(mask: np.ndarray, overlay: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box of ``mask``, less edge rows/columns that are more than half overlay."""
    ys, xs = np.nonzero(mask)
    if not len(ys):
        return (0, 0, 0, 0)
    t, b, l, r = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    while b - t > 1 and overlay[t, l:r].mean() > 0.5:
        t += 1
    while b - t > 1 and overlay[b - 1, l:r].mean() > 0.5:
        b -= 1
    while r - l > 1 and overlay[t:b, l].mean() > 0.5:
        l += 1
    while r - l > 1 and overlay[t:b, r - 1].mean() > 0.5:
        r -= 1
    sub = mask[t:b, l:r]
    ys, xs = np.nonzero(sub)
    if not len(ys):
        return (0, 0, 0, 0)
    return (t + int(ys.min()), l + int(xs.min()), t + int(ys.max()) + 1, l + int(xs.max()) + 1)


def mask_at(area: ContentArea, height: int, width: int) -> np.ndarray:
    """The cropped mask at a stored size, conservative: a stored pixel is content only if every
    frame pixel it averages is."""
    m = area.crop(area.mask).astype(np.float32)
    if m.shape != (height, width):
        m = cv2.resize(m, (width, height), interpolation=cv2.INTER_AREA)
    return m >= 0.999


def stored_size(box: tuple[int, int, int, int], short_side: int) -> tuple[int, int]:
    """(h, w) of a frame cropped to ``box`` with its short side at ``short_side`` (never enlarged)."""
    t, l, b, r = box
    h, w = b - t, r - l
    s = min(1.0, short_side / min(h, w))
    return max(1, math.floor(h * s + 0.5)), max(1, math.floor(w * s + 0.5))
