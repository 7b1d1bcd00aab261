"""``--camera-region auto``: fit the camera region into the cavity in front of the liver.

How the region is found (:func:`fit_camera_region`), all with the Embree ray caster:

1. **Candidates**: a regular grid of about 20^3 points over the liver's bounding box grown by
   its own size (the whole scene's box without a liver), kept where they lie on the anterior
   side of the liver's centre (the scene's ``anterior`` direction).
2. **Free space**: a candidate must lie outside every closed organ and, when the scene has an
   abdominal wall, inside the cavity the wall closes around
   (:meth:`~sim2real.render.raycast.RayCaster.free_space`).
3. **Clearance**: the distance to the nearest surface along 26 directions (the axes, the face
   and the corner diagonals of a cube); a ray that hits nothing escapes. Candidates need at
   least ``clearance_mm`` (20 mm: the random views keep that from the liver) and at most
   :data:`MAX_ESCAPING` of the 26 rays escaping (a wall with holes, as CT-derived meshes
   have, lets some escape from anywhere).
4. **Centre**: of the candidates that see the liver (the ray towards the centre of the liver's
   bounding box first meets the liver), the one with the best score: the clearance (capped at
   60 mm, beyond which views only look from farther away) less 10 mm per escaping ray; ties go
   to the one nearest the liver.
5. **Radii**: along each world axis, half the free distance from the centre in the nearer of
   the two directions, at most 60 mm; then the ellipsoid is checked with 256 random points and
   shrunk by 0.7 until at least 97 % of them are free space with at most :data:`MAX_ESCAPING`
   escaping rays.

A scene with no such place (no cavity in front of the liver, organs that touch the wall) is
refused with one line: give ``--camera-region`` by hand then.
"""

from __future__ import annotations

import itertools

import numpy as np

from sim2real.errors import UserError
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import CameraRegion

_DIRS26 = np.array([d for d in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(d)])
_DIRS26 /= np.linalg.norm(_DIRS26, axis=1, keepdims=True)
CLEARANCE_CAP_MM = 60.0
MAX_RADIUS_MM = 60.0
FREE_SHARE = 0.97
MAX_ESCAPING = 8
"""Of the 26 clearance rays, at most this many may escape from a camera-region point."""
ESCAPE_PENALTY_MM = 10.0


def clearance(caster: RayCaster, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distance to the nearest surface along 26 directions, number of escaping rays) per point."""
    n = len(points)
    hits = caster.intersect(np.repeat(points, len(_DIRS26), axis=0), np.tile(_DIRS26, (n, 1)))
    t = hits["t"].reshape(n, len(_DIRS26))
    miss = (hits["object"] < 0).reshape(n, len(_DIRS26))
    return np.where(miss, np.inf, t).min(axis=1), miss.sum(axis=1)


def _usable(caster: RayCaster, points: np.ndarray, max_escaping: int) -> np.ndarray:
    _, escaping = clearance(caster, points)
    return caster.free_space(points) & (escaping <= max_escaping)


def fit_camera_region(caster: RayCaster, clearance_mm: float = 20.0, grid: int = 20, seed: int = 0) -> CameraRegion:
    """A camera region inside the cavity in front of the liver (see the module docstring)."""
    scene = caster.scene
    livers = scene.objects_of("liver")
    boxes = scene.bounds()
    if livers:
        lo, hi = boxes[livers].min(axis=(0, 1)), boxes[livers].max(axis=(0, 1))
    else:
        lo, hi = boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)
    size = hi - lo
    centre = 0.5 * (lo + hi)
    axes = [np.linspace(lo[a] - size[a], hi[a] + size[a], grid) for a in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    pts = pts[(pts - centre) @ scene.anterior > 0]
    pts = pts[caster.free_space(pts)]
    if len(pts):
        clear, escaping = clearance(caster, pts)
        keep = (clear >= clearance_mm) & (escaping <= MAX_ESCAPING)
        pts, clear, escaping = pts[keep], clear[keep], escaping[keep]
    if livers and len(pts):
        d = centre[None] - pts
        dist = np.linalg.norm(d, axis=1)
        hits = caster.intersect(pts, d / dist[:, None])
        sees = np.isin(hits["object"], livers)
        pts, clear, escaping = pts[sees], clear[sees], escaping[sees]
    if not len(pts):
        raise UserError(f"could not fit a camera region into scene '{scene.name}': no free space at least "
                        f"{clearance_mm:g} mm from every surface in front of the liver; give --camera-region CX,CY,CZ,RX,RY,RZ")
    score = np.minimum(clear, CLEARANCE_CAP_MM) - ESCAPE_PENALTY_MM * escaping
    best = np.flatnonzero(score >= score.max() - 1e-6)
    k = best[np.argmin(np.linalg.norm(pts[best] - centre, axis=1))]
    c = pts[k]
    radii = np.empty(3)
    for a in range(3):
        e = np.zeros((2, 3))
        e[0, a], e[1, a] = 1.0, -1.0
        h = caster.intersect(np.repeat(c[None], 2, axis=0), e)
        radii[a] = min(0.5 * float(h["t"].min()), MAX_RADIUS_MM)
    rng = np.random.default_rng(seed)
    for _ in range(8):
        region = CameraRegion(c, np.maximum(radii, 1.0))
        if _usable(caster, region.sample(rng, 256), MAX_ESCAPING).mean() >= FREE_SHARE:
            return region
        radii *= 0.7
    raise UserError(f"could not fit a camera region into scene '{scene.name}' (the free space in front of the liver "
                    f"is too narrow); give --camera-region CX,CY,CZ,RX,RY,RZ")
