"""Lens distortion taken out of the footage (``sim2real realset --calibration FILE``).

The simulated cameras are pinholes. A laparoscope's wide-angle lens bends straight lines (barrel
distortion), so its frames are undistorted with the endoscope's calibration before anything else
(content area, crops, labels): OpenCV's ``initUndistortRectifyMap`` and ``remap``, the same camera
matrix kept for the undistorted frames, pixels mapped from outside the frame black (the content
area then masks them). The calibration's camera matrix, carried through the crop and the resize
of each source, gives the stored frames' pinhole intrinsics (:func:`stored_intrinsics`): the
camera to simulate (``data.intrinsics``, ``scene trajectory --intrinsics``).

The calibration file is JSON in pixels of the calibrated image size::

    {"width": 1920, "height": 1080, "fx": 1100.0, "fy": 1100.0, "cx": 960.0, "cy": 540.0,
     "dist": [-0.35, 0.12, 0.0, 0.0, -0.02]}

``dist`` is OpenCV's coefficient vector (k1, k2, p1, p2[, k3[, k4, k5, k6]]) and the camera matrix
OpenCV's, as ``cv2.calibrateCamera`` gives them (pixel centres at integer coordinates). Frames of
another size with the same aspect (within 1 %) scale the camera matrix; another aspect is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from sim2real.errors import UserError
from sim2real.fileio import read_json

DIST_LENGTHS = (4, 5, 8)


@dataclass(frozen=True)
class Calibration:
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray

    def at(self, height: int, width: int) -> np.ndarray:
        """The camera matrix for frames of ``height`` x ``width`` (a uniform scale of the
        calibrated size)."""
        sx, sy = width / self.width, height / self.height
        if abs(sx / sy - 1.0) > 0.01:
            raise UserError(f"frames of {width}x{height} do not have the aspect of the calibration's "
                            f"{self.width}x{self.height}")
        K = self.K.copy()  # pixel centres at integers: a centre u maps to (u + 0.5) * s - 0.5
        K[0, 0], K[0, 2] = K[0, 0] * sx, (K[0, 2] + 0.5) * sx - 0.5
        K[1, 1], K[1, 2] = K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5
        return K


def read_calibration(path) -> Calibration:
    """The calibration in JSON file ``path`` (module docstring); one clear line when it is not one."""
    data = read_json(path, "calibration")
    where = f"calibration {path}"
    if not isinstance(data, dict):
        raise UserError(f"{where} must hold a JSON object")
    missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "dist") if k not in data]
    if missing:
        raise UserError(f"{where} lacks {', '.join(missing)}")
    try:
        w, h = int(data["width"]), int(data["height"])
        fx, fy, cx, cy = (float(data[k]) for k in ("fx", "fy", "cx", "cy"))
        dist = np.asarray(data["dist"], np.float64).ravel()
    except (TypeError, ValueError):
        raise UserError(f"{where}: width and height are integers, fx, fy, cx, cy numbers and dist a list of "
                        "numbers") from None
    if w < 8 or h < 8:
        raise UserError(f"{where}: the calibrated size {w}x{h} is too small")
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx <= 0 or fy <= 0 or not (0 < cx < w and 0 < cy < h):
        raise UserError(f"{where}: needs positive focal lengths and the principal point inside the {w}x{h} image")
    if len(dist) not in DIST_LENGTHS or not np.isfinite(dist).all():
        raise UserError(f"{where}: dist holds 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]), "
                        f"got {len(dist)}")
    return Calibration(w, h, np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), dist)


class Undistorter:
    """Undistorts frames of any size the calibration fits; the maps are made once per size."""

    def __init__(self, calibration: Calibration):
        self.calibration = calibration
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, image: np.ndarray, labels: bool = False) -> np.ndarray:
        """``image`` undistorted: bilinear, black outside; ``labels=True``: nearest, 255 outside."""
        h, w = image.shape[:2]
        if (h, w) not in self._maps:
            K = self.calibration.at(h, w)
            self._maps[h, w] = cv2.initUndistortRectifyMap(K, self.calibration.dist, None, K, (w, h), cv2.CV_32FC1)
        mx, my = self._maps[h, w]
        if labels:
            return cv2.remap(image, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=255)
        return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def stored_intrinsics(K: np.ndarray, box: tuple[int, int, int, int], size: tuple[int, int]) -> list[float]:
    """[fx, fy, cx, cy] of frames cropped to ``box`` (top, left, bottom, right) of frames with the
    OpenCV camera matrix ``K`` (pixel centres at integer coordinates) and resized to ``size``
    (h, w), in the ray caster's convention (pixel edges at integers: a centre at +0.5)."""
    t, l, b, r = box
    sy, sx = size[0] / (b - t), size[1] / (r - l)
    cx, cy = K[0, 2] + 0.5, K[1, 2] + 0.5
    return [float(K[0, 0] * sx), float(K[1, 1] * sy), float((cx - l) * sx), float((cy - t) * sy)]
