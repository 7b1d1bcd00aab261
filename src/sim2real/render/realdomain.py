"""A procedural stand-in for real laparoscopic video (the embedded target domain B), with labels.

Appearance is defined in 3D: every material is a solid texture of the surface point in its
object's local frame (``point - object bounding-box minimum``, mm; see
:mod:`sim2real.render.solid_texture`), so a point has the same albedo in every view. Materials:

* abdominal wall: pinkish white, milky patches and a reddish blush, faint muscle striation
  showing through, branching red vessel trees whose calibres taper from trunks to twigs
  (:class:`~sim2real.render.solid_texture.VesselTree`) and a faint capillary mesh (edges of
  domain-warped Voronoi cells); wrapped diffuse for a translucent look;
* liver: dark red-brown, glossy, fine mottling and a faint lobular (cellular) pattern;
* fat (and stomach, which the procedural scenes put in the fat object): yellow-orange lobules of
  varying tint with reddish septa and thin vessels between them, each lobule bulging (bump map);
* gallbladder: greenish, glossy, a few vessels; ligament: whitish, fibrous streaks, fat patches.

Shading: one light on the camera with a distance falloff and a spot profile (the centre of the
view is brightest), wrapped Lambert diffuse plus Blinn-Phong specular (with the light on the
camera the half vector is the view direction) on normals perturbed by each material's bump
field, so wet highlights break up into glints; then lens vignetting, a filmic tone curve, sRGB,
an optional circular endoscope mask, a slight blur and sensor noise. Each scene draws a mild
variation of tissue colours, vessel density, lobule size and gloss from its appearance seed.

Not modelled: smoke, blood, instruments, tissue deformation, motion blur, lens distortion.

Label PNGs hold the class index per pixel in :data:`sim2real.scene.scene.CLASSES` order
(0 liver, 1 fat, 2 ligament, 3 abdominal_wall, 4 gallbladder) and :data:`LABEL_BACKGROUND` = 255
for pixels without a surface (or outside the endoscope mask). They are palette PNGs: reading
them as arrays gives the indices, image viewers show :data:`LABEL_PALETTE` colours.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Sequence

import numpy as np

from sim2real.errors import UserError
from sim2real.render.gbuffer import GBuffer
from sim2real.render.solid_texture import (
    CellField, Noise, VesselTree, hash_unit, line_profile, smoothstep, surface_samples,
)
from sim2real.scene.scene import CLASSES, LABEL_BACKGROUND, LABEL_PALETTE

FORMAT = "sim2real-realdomain/1"


# Tags of derived seeds (see :func:`derive_seed`).
_APPEARANCE, _POSE, _TRAJECTORY, _FRAME, _SEQUENCE_FRAME = 11, 12, 13, 14, 15


def derive_seed(seed: int, *keys: int) -> int:
    """An independent 32-bit seed for (seed, keys...): frames get their own seeds, so the output
    does not depend on the number of workers or on the order in which frames are rendered."""
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *[int(k) for k in keys]]).generate_state(1)[0])


def _stable(text: str) -> int:
    """A hash of a string that is the same in every process (unlike ``hash``)."""
    import zlib

    return zlib.crc32(text.encode())


def srgb_to_linear(c) -> np.ndarray:
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(c, 1 / 2.4) - 0.055).astype(np.float32)


# --- per-scene appearance ------------------------------------------------------------------------


@dataclass
class Appearance:
    """The look of one scene. Colours are sRGB in [0, 1]; sizes in mm."""

    seed: int = 0
    wall: tuple[float, float, float] = (0.92, 0.62, 0.62)
    wall_milky: tuple[float, float, float] = (0.97, 0.86, 0.80)
    wall_muscle: tuple[float, float, float] = (0.75, 0.38, 0.36)
    artery: tuple[float, float, float] = (0.86, 0.16, 0.12)
    vein: tuple[float, float, float] = (0.66, 0.10, 0.14)
    vessel_density: float = 1.0
    """Multiplies the share of Voronoi edges that carry a vessel."""
    vessel_width: float = 1.0
    liver: tuple[float, float, float] = (0.36, 0.13, 0.13)
    liver_dark: tuple[float, float, float] = (0.24, 0.07, 0.10)
    fat: tuple[float, float, float] = (0.97, 0.71, 0.24)
    fat_deep: tuple[float, float, float] = (0.93, 0.52, 0.15)
    fat_septum: tuple[float, float, float] = (0.85, 0.40, 0.16)
    lobule_mm: float = 9.0
    gallbladder: tuple[float, float, float] = (0.42, 0.48, 0.24)
    ligament: tuple[float, float, float] = (0.82, 0.68, 0.64)
    gloss: float = 1.0
    light_reference_mm: float = 70.0
    """Distance at which the light's falloff equals 1."""
    exposure: float = 1.0

    @classmethod
    def sample(cls, seed: int) -> "Appearance":
        """Mild per-scene variation around the defaults (same seed, same look)."""
        rng = np.random.default_rng(derive_seed(seed, 1))
        base = cls(seed=int(seed))

        def tint(c, brightness=0.05, hue=0.03):
            c = np.asarray(c) * (1.0 + rng.normal(0.0, brightness))
            c = c * (1.0 + rng.normal(0.0, hue, size=3))
            return tuple(float(x) for x in np.clip(c, 0.02, 0.98))

        values = {
            "seed": int(seed),
            "vessel_density": float(rng.uniform(0.7, 1.3)),
            "vessel_width": float(rng.uniform(0.8, 1.25)),
            "lobule_mm": float(rng.uniform(7.0, 12.0)),
            "gloss": float(rng.uniform(0.75, 1.25)),
            "light_reference_mm": float(rng.uniform(60.0, 80.0)),
            "exposure": float(rng.uniform(0.92, 1.08)),
        }
        for f in fields(cls):
            if f.name not in values:
                values[f.name] = tint(getattr(base, f.name))
        return cls(**values)

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass
class RenderOptions:
    """Camera and sensor settings of the stand-in frames."""

    height: int = 256
    width: int = 512
    fov_x_deg: float = 75.0
    mask: bool = False
    """Black out the corners outside the endoscope's circular image (labels 255 there)."""
    mask_radius: float = 0.5
    """Radius of the circular mask as a fraction of the image width (0.5: the circle touches
    the left and right borders and cuts the corners)."""
    blur_px: float = 0.6
    """Gaussian blur sigma in pixels (0 = none)."""
    noise: float = 0.012
    """Sensor noise standard deviation at full brightness (0 = none)."""
    vignetting: float = 0.5
    saturation: float = 1.25
    """Colour saturation applied by the camera (1 = none)."""
    """Brightness lost in the image corners by the lens (0 = none)."""

    def to_json(self) -> dict:
        return asdict(self)


# --- materials -------------------------------------------------------------------------------------


@dataclass
class Surface:
    """What a material returns for N surface points."""

    albedo: np.ndarray  # (N, 3) linear RGB in [0, 1]
    bump: np.ndarray  # (N, 3) gradient of a height field (mm/mm); tilts the shading normal
    specular: float  # Blinn-Phong strength k_s (normalised: peak k_s (n + 8) / 8)
    shininess: float
    wrap: float  # wrapped diffuse: 0 Lambert, > 0 softer (translucent look)
    sheen: float = 0.0  # broad low-exponent specular lobe (wet film)
    diffuse_bump: float = 1.0  # share of the bump that the diffuse term sees (micro-relief: small)


def _lerp(a: np.ndarray, b, t: np.ndarray) -> np.ndarray:
    b = np.asarray(b, dtype=np.float32)
    return a + (b - a) * t[:, None]


def _full(n: int, c) -> np.ndarray:
    return np.tile(srgb_to_linear(c)[None], (n, 1))


class _Object:
    """Lazily built solid-texture fields of one scene object (mesh in its local frame)."""

    def __init__(self, mesh, seed: int, facing_point: np.ndarray | None):
        self.origin = np.asarray(mesh.bounds[0], dtype=np.float64)
        self.vertices = np.asarray(mesh.vertices, dtype=np.float64) - self.origin
        self.faces = np.asarray(mesh.faces, dtype=np.int64)
        self.seed = seed
        self.noise = Noise(seed)
        self.noise2 = Noise(seed + 1)
        # Culling the far side needs outward normals: only for closed, consistently wound meshes.
        oriented = facing_point is not None and bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)
        self._facing = np.asarray(facing_point, np.float64) - self.origin if oriented else None
        self._fields: dict = {}
        self._samples: dict = {}
        extent = self.vertices.max(0) - self.vertices.min(0)
        self.long_axis = int(np.argmax(extent))

    def samples(self, spacing: float) -> np.ndarray:
        """Surface points about ``spacing`` apart, on the side facing the camera region."""
        key = round(spacing, 3)
        if key not in self._samples:
            pts = surface_samples(self.vertices, self.faces, spacing, self.seed + 101)
            if self._facing is not None:
                # Drop the far side of closed shells (e.g. the wall's outer surface) that no
                # camera in the region can see; queries there would still work, only coarser.
                from scipy.spatial import cKDTree

                tri = self.vertices[self.faces]
                centres = tri.mean(axis=1)
                normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
                _, f = cKDTree(centres).query(pts)
                to_region = self._facing - pts
                to_region /= np.maximum(np.linalg.norm(to_region, axis=1, keepdims=True), 1e-12)
                facing = np.einsum("ij,ij->i", normals[f], to_region)
                # Normals of closed meshes point outwards: keep points that see the region
                # (facing > -0.5) - for the wall, the region lies on the side its inner faces face.
                keep = facing > -0.5
                if keep.sum() > 16:
                    pts = pts[keep]
            self._samples[key] = pts
        return self._samples[key]

    def tree(self, name: str, spacing: float, r_leaf: float, r_max: float, prune: int) -> VesselTree:
        """A precomputed vessel tree on the surface (see :class:`VesselTree`)."""
        if name not in self._fields:
            self._fields[name] = VesselTree(self.samples(0.5 * spacing), spacing, self.seed + _stable(name) % 100_000,
                                            r_leaf, r_max, prune)
        return self._fields[name]

    def cells(self, name: str, cell: float, warp=None) -> CellField:
        """A cellular field of cell size ``cell`` near the (optionally warped) surface."""
        if name not in self._fields:
            s = self.samples(min(cell, 8.0))
            if warp is not None:
                s = s + warp(s, None)
            self._fields[name] = CellField(s, cell, self.seed + _stable(name) % 100_000 + 3)
        return self._fields[name]


def _vessels(
    obj: _Object, name: str, q: np.ndarray, fp: np.ndarray, cell: float, keep: float,
    radius: tuple[float, float], depth_mm: float, warp=None, edges: dict | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Vessel coverage in [0, 1] along a random subset of the Voronoi faces of cells of size
    ``cell`` (mm), and a per-vessel value in [0, 1) (e.g. artery vs vein). Each kept face gets a
    random radius and a random depth under the surface that blurs and fades it. With ``edges``
    (a dict) also the distance to the nearest face and its direction, for bump mapping."""
    field_ = obj.cells(name, cell, warp)
    # Vessels much thinner than a pixel fade out (smoothly) and are not even looked up.
    visible = smoothstep(0.06, 0.14, radius[1] / np.sqrt(radius[1] ** 2 + (0.5 * fp) ** 2))
    sel = np.nonzero(visible > 0)[0]
    cov_all = np.zeros(len(q), np.float32)
    kind_all = np.zeros(len(q), np.float32)
    if len(sel) == 0:
        return cov_all, kind_all
    q, fp, visible = q[sel], fp[sel], visible[sel]
    cq = field_.query(q)
    if edges is not None:
        edges["edge"] = np.full(len(cov_all), np.inf, np.float32)
        edges["edge"][sel] = cq.edge
        edges["edge_dir"] = np.zeros((len(cov_all), 3), np.float32)
        edges["edge_dir"][sel] = cq.edge_dir
    eid = cq.edge_id()
    salt = obj.seed + _stable(name) % 100_000
    u_keep = hash_unit(eid, salt)
    u_rad = hash_unit(eid, salt + 1)
    u_depth = hash_unit(eid, salt + 2)
    r = radius[0] + (radius[1] - radius[0]) * u_rad
    depth = depth_mm * u_depth
    blurred = np.sqrt(r * r + depth * depth)
    cov = line_profile(cq.edge, blurred, fp) * (r / blurred) ** 0.5
    # Fade out near the tips of the kept set: keep edges with u < keep, soft over 0.08.
    cov = cov * smoothstep(keep + 0.04, keep - 0.04, u_keep) * visible
    cov_all[sel] = cov
    kind_all[sel] = hash_unit(eid, salt + 3)
    return cov_all, kind_all


def _tree_vessels(obj: _Object, name: str, p: np.ndarray, n: np.ndarray, fp: np.ndarray, w: np.ndarray,
                  spacing: float, r_leaf: float, r_max: float, prune: int, depth_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Coverage in [0, 1] of the vessels of a :class:`VesselTree` and a per-tree value in [0, 1)
    (artery or vein). The query point is displaced by ``w`` along the surface only (tortuosity)."""
    tree = obj.tree(name, spacing, r_leaf, r_max, prune)
    w = w - np.einsum("ij,ij->i", w, n)[:, None] * n
    d, r, ids = tree.query(p + w)
    depth = depth_mm * hash_unit(ids, 3)
    blurred = np.sqrt(r * r + depth * depth)
    cov = line_profile(d, blurred, fp) * (r / np.maximum(blurred, 1e-9)) ** 0.5
    cov[~np.isfinite(d)] = 0.0
    return cov.astype(np.float32), hash_unit(ids, 4)


def _warp_fn(obj: _Object, amp_big: float, scale_big: float, amp_small: float, scale_small: float):
    def warp(p: np.ndarray, fp) -> np.ndarray:
        w = amp_big * obj.noise2.vector(p, scale_big, octaves=2)
        w += amp_small * obj.noise2.vector(p * 1.37 + 11.0, scale_small, octaves=1)
        return w.astype(np.float64)

    return warp


def material_wall(obj: _Object, app: Appearance, p: np.ndarray, n: np.ndarray, fp: np.ndarray) -> Surface:
    N = len(p)
    nz = obj.noise
    large = nz.fbm(p, 45.0, 3)
    milky = smoothstep(-0.2, 1.0, large)
    c = _lerp(_full(N, app.wall), srgb_to_linear(app.wall_milky), 0.45 * milky)
    # Muscle fibres shimmering through the translucent peritoneum: noise stretched along an axis.
    stretch = np.array([1.0, 1.0, 1.0])
    stretch[(obj.long_axis + 1) % 3] = 14.0
    fib = nz.fbm(p / stretch, 2.5, 2, footprint=fp, first_octave=4)
    c = _lerp(c, srgb_to_linear(app.wall_muscle), 0.12 * smoothstep(0.0, 1.5, fib) * (1.0 - milky))
    c *= (1.0 + 0.02 * nz.fbm(p, 4.0, 2, footprint=fp, first_octave=2))[:, None]
    # Vascular blush: reddish patches where the capillary bed is denser.
    blush = smoothstep(0.3, 1.5, -large)
    c = _lerp(c, srgb_to_linear(app.wall_muscle), 0.15 * blush)
    # Branching vessel networks of three calibres along domain-warped Voronoi faces.
    warp = _warp_fn(obj, 7.0, 40.0, 1.6, 7.0)
    w = warp(p, fp)
    q = p + w
    d = app.vessel_density
    wv = app.vessel_width
    art, vein = srgb_to_linear(app.artery), srgb_to_linear(app.vein)
    patch = smoothstep(-0.6, 0.6, obj.noise2.fbm(p, 60.0, 2, first_octave=6))
    cov, kind = _tree_vessels(obj, "t_wall", p, n, fp, w, 6.0, 0.12 * wv, 1.6 * wv, max(2, round(4 / d)), 0.6)
    col = art[None] + (vein - art)[None] * (kind[:, None] > 0.5)
    c = c + (col - c) * (0.92 * cov)[:, None]
    # A faint capillary mesh in patches.
    cov, kind = _vessels(obj, "v_fine", q, fp, 5.0, 0.4 * d, (0.08 * wv, 0.15 * wv), 0.15, warp)
    c = _lerp(c, srgb_to_linear(app.artery), 0.5 * cov * patch)
    _, g = nz.fbm(p, 12.0, 2, footprint=fp, grad=True, first_octave=5)
    return Surface(np.clip(c, 0, 1), 0.15 * g, 0.05 * app.gloss, 40.0, 0.45, sheen=0.05)


def material_liver(obj: _Object, app: Appearance, p: np.ndarray, n: np.ndarray, fp: np.ndarray) -> Surface:
    N = len(p)
    nz = obj.noise
    big = nz.fbm(p, 40.0, 2)
    c = _lerp(_full(N, app.liver), srgb_to_linear(app.liver_dark), 0.8 * smoothstep(-1.5, 1.5, big))
    mott = nz.fbm(p, 4.0, 3, footprint=fp, first_octave=3)
    c *= (1.0 + 0.05 * mott)[:, None]
    # Lobules (~1.5-2 mm): slightly paler borders and a dark central vein dot.
    # Only resolved close up: faded out (and not looked up) beyond 0.9 mm per pixel.
    near = smoothstep(0.9, 0.5, fp)
    sel = np.nonzero(near > 0)[0]
    if len(sel):
        cq = obj.cells("lobules", 1.8).query(p[sel])
        border = line_profile(cq.edge, np.full(len(sel), 0.08, np.float32), fp[sel]) * near[sel]
        central = line_profile(cq.f1, np.full(len(sel), 0.12, np.float32), fp[sel]) * near[sel]
        c[sel] = _lerp(c[sel], srgb_to_linear((0.55, 0.26, 0.24)), 0.12 * border)
        c[sel] *= (1.0 - 0.10 * central)[:, None]
    # Wet micro-relief breaks the highlight into glints; broad undulations bend it.
    _, g1 = nz.fbm(p, 3.0, 3, footprint=fp, grad=True, first_octave=6)
    _, g2 = obj.noise2.fbm(p, 25.0, 2, grad=True)
    bump = 0.07 * g1 + 2.0 * g2
    return Surface(np.clip(c, 0, 1), bump, 0.035 * app.gloss, 250.0, 0.15, sheen=0.04, diffuse_bump=0.2)


def material_fat(obj: _Object, app: Appearance, p: np.ndarray, n: np.ndarray, fp: np.ndarray) -> Surface:
    N = len(p)
    nz = obj.noise
    warp = _warp_fn(obj, 0.5 * app.lobule_mm, 4.0 * app.lobule_mm, 0.0, 1.0)
    q = p + warp(p, fp)
    cq = obj.cells("lobules", app.lobule_mm, warp).query(q)
    t1 = hash_unit(cq.id1, 5)
    t2 = hash_unit(cq.id1, 6)
    base = _lerp(_full(N, app.fat), srgb_to_linear(app.fat_deep), 0.8 * t1 ** 1.5)
    base *= (0.88 + 0.2 * t2)[:, None]
    base *= (1.0 + 0.07 * nz.fbm(p, 1.6, 2, footprint=fp, first_octave=2))[:, None]
    # Lobule rims turn orange-red towards the septa between lobules.
    inner = smoothstep(0.0, 0.35 * app.lobule_mm, cq.edge)
    c = _lerp(base, srgb_to_linear(app.fat_septum), 0.3 * (1.0 - inner) ** 2)
    # Thin vessels in the septa (a subset of lobule edges) and larger ones between lobule groups.
    eid = cq.edge_id()
    on = smoothstep(0.3 * app.vessel_density + 0.04, 0.3 * app.vessel_density - 0.04, hash_unit(eid, 21))
    thin = line_profile(cq.edge, np.full(N, 0.07 * app.vessel_width, np.float32), fp) * on
    c = _lerp(c, srgb_to_linear(app.artery), 0.8 * thin)
    big: dict = {}
    cov, kind = _vessels(obj, "v_septa", q, fp, 3.5 * app.lobule_mm, 0.6 * app.vessel_density,
                         (0.15 * app.vessel_width, 0.35 * app.vessel_width), 0.2, warp, edges=big)
    # Deeper, darker clefts between groups of lobules.
    cleft = np.exp(-big["edge"] / (0.12 * app.lobule_mm))
    c = _lerp(c, srgb_to_linear(app.fat_septum) * 0.7, 0.35 * cleft)
    col = np.where(kind[:, None] > 0.4, srgb_to_linear(app.artery)[None], srgb_to_linear(app.vein)[None])
    c = c + (col - c) * (0.85 * cov)[:, None]
    # Each lobule bulges like a cap around its feature point: height -k F1^2 / L, so its
    # gradient is -2 k (q - c1) / L (the shading uses the part tangent to the surface).
    bump = (-2.0 * 0.55 / app.lobule_mm) * cq.delta1 + (0.4 * cleft)[:, None] * big["edge_dir"]
    _, g = nz.fbm(p, 2.0, 2, footprint=fp, grad=True, first_octave=7)
    bump = bump + 0.12 * g
    return Surface(np.clip(c, 0, 1), bump, 0.06 * app.gloss, 120.0, 0.25, sheen=0.05)


def material_gallbladder(obj: _Object, app: Appearance, p: np.ndarray, n: np.ndarray, fp: np.ndarray) -> Surface:
    N = len(p)
    nz = obj.noise
    c = _full(N, app.gallbladder) * (1.0 + 0.15 * nz.fbm(p, 12.0, 3, footprint=fp))[:, None]
    c = _lerp(c, srgb_to_linear((0.62, 0.62, 0.45)), 0.3 * smoothstep(0.3, 1.5, nz.fbm(p, 20.0, 2, first_octave=4)))
    warp = _warp_fn(obj, 2.5, 15.0, 0.6, 4.0)
    cov, _ = _vessels(obj, "v", p + warp(p, fp), fp, 9.0, 0.5 * app.vessel_density, (0.08, 0.2), 0.2, warp)
    c = _lerp(c, srgb_to_linear(app.artery), 0.7 * cov)
    _, g = nz.fbm(p, 3.0, 2, footprint=fp, grad=True, first_octave=5)
    return Surface(np.clip(c, 0, 1), 0.1 * g, 0.05 * app.gloss, 150.0, 0.1, sheen=0.06)


def material_ligament(obj: _Object, app: Appearance, p: np.ndarray, n: np.ndarray, fp: np.ndarray) -> Surface:
    N = len(p)
    nz = obj.noise
    stretch = np.array([1.0, 1.0, 1.0])
    stretch[obj.long_axis] = 12.0
    fib = nz.fbm(p / stretch, 1.2, 3, footprint=fp)
    c = _full(N, app.ligament) * (1.0 + 0.04 * fib)[:, None]
    fatty = smoothstep(0.2, 1.2, nz.fbm(p, 15.0, 2, first_octave=4))
    c = _lerp(c, srgb_to_linear(app.fat), 0.35 * fatty)
    warp = _warp_fn(obj, 3.0, 20.0, 0.8, 5.0)
    cov, _ = _vessels(obj, "v", p + warp(p, fp), fp, 12.0, 0.5 * app.vessel_density, (0.1, 0.25), 0.15, warp)
    c = _lerp(c, srgb_to_linear(app.artery), 0.75 * cov)
    _, g = nz.fbm(p / stretch, 1.5, 2, footprint=fp, grad=True)
    return Surface(np.clip(c, 0, 1), 0.15 * g, 0.05 * app.gloss, 30.0, 0.5, sheen=0.03)


MATERIALS = {
    "abdominal_wall": material_wall,
    "liver": material_liver,
    "fat": material_fat,
    "gallbladder": material_gallbladder,
    "ligament": material_ligament,
}


class SceneMaterial:
    """Solid textures of every object of a scene for one :class:`Appearance`. Fields are built
    on first use (a second or so per scene) and then reused for every frame."""

    def __init__(self, scene, appearance: Appearance):
        self.scene = scene
        self.appearance = appearance
        centre = scene.camera_region.center
        self.objects = [
            _Object(o.mesh, derive_seed(appearance.seed, 2, k), centre) for k, o in enumerate(scene.objects)
        ]

    def surface(self, object_id: np.ndarray, points: np.ndarray, normals: np.ndarray, footprint: np.ndarray):
        """Albedo (N, 3, linear), bump gradient (N, 3) and per-point specular strength,
        shininess, wrap and sheen for surface points of the given objects."""
        N = len(points)
        out = {
            "albedo": np.zeros((N, 3), np.float32),
            "bump": np.zeros((N, 3), np.float32),
            "specular": np.zeros(N, np.float32),
            "shininess": np.ones(N, np.float32),
            "wrap": np.zeros(N, np.float32),
            "sheen": np.zeros(N, np.float32),
            "diffuse_bump": np.zeros(N, np.float32),
        }
        for k in np.unique(object_id):
            sel = np.nonzero(object_id == k)[0]
            obj = self.objects[int(k)]
            p = points[sel].astype(np.float64) - obj.origin
            s = MATERIALS[self.scene.objects[int(k)].cls](obj, self.appearance, p, normals[sel], footprint[sel])
            out["albedo"][sel] = s.albedo
            out["bump"][sel] = s.bump
            out["specular"][sel] = s.specular
            out["shininess"][sel] = s.shininess
            out["wrap"][sel] = s.wrap
            out["sheen"][sel] = s.sheen
            out["diffuse_bump"][sel] = s.diffuse_bump
        return out


# --- one frame -------------------------------------------------------------------------------------


@dataclass
class RealFrame:
    """One stand-in frame and its intermediate buffers (float buffers are (H, W[, 3]))."""

    image: np.ndarray  # uint8 (H, W, 3) sRGB
    label: np.ndarray  # uint8 (H, W): class index, 255 = background
    albedo: np.ndarray  # float32 (H, W, 3) linear albedo, view independent; 0 on background
    shading: np.ndarray  # float32 (H, W) diffuse irradiance factor (light x falloff x cosine)
    specular: np.ndarray  # float32 (H, W) specular radiance added on top (linear)
    radiance: np.ndarray = field(repr=False, default=None)  # float32 (H, W, 3) before the camera


def light_falloff(distance: np.ndarray, reference_mm: float) -> np.ndarray:
    """Irradiance from the light on the camera at ``distance`` mm, 1 at ``reference_mm``:
    (1 + a) / (a + (d / d_ref)^2) with a = 0.25: inverse square far away, softened close up
    (the light leaves the scope through an extended fibre bundle, not a point)."""
    a = 0.25
    x = np.asarray(distance, dtype=np.float32) / np.float32(reference_mm)
    return ((1.0 + a) / (a + x * x)).astype(np.float32)



def circular_mask(height: int, width: int, radius: float) -> np.ndarray:
    """Coverage in [0, 1] (float32, H x W) of the endoscope's circular image, anti-aliased over
    one pixel; ``radius`` is a fraction of the width."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    r = np.hypot(xx + 0.5 - width / 2, yy + 0.5 - height / 2)
    return np.clip(radius * width - r + 0.5, 0.0, 1.0).astype(np.float32)


def render_frame(g: GBuffer, material: SceneMaterial, options: RenderOptions | None = None, seed: int = 0) -> RealFrame:
    """Shade one G-buffer with the scene's solid textures (see the module docstring)."""
    import cv2

    opt = options or RenderOptions()
    app = material.appearance
    h, w = g.height, g.width
    hit = g.mask.reshape(-1)
    idx = np.nonzero(hit)[0]
    pts = g.points.reshape(-1, 3)[idx]
    nrm = g.normal.reshape(-1, 3)[idx].astype(np.float32)
    dist = g.distance.reshape(-1)[idx].astype(np.float32)
    eye = g.camera.position.astype(np.float32)
    v = eye[None] - pts.astype(np.float32)
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
    ndv0 = np.clip(np.einsum("ij,ij->i", nrm, v), 0.0, 1.0)
    focal = float(g.K[0, 0])
    footprint = dist / focal / np.sqrt(np.maximum(ndv0, 0.15))  # mm per pixel on the surface

    s = material.surface(g.object_id.reshape(-1)[idx], pts, nrm, footprint)
    # Bump mapping: tilt the normal against the tangential part of the height gradient.
    b = s["bump"]
    b_t = b - np.einsum("ij,ij->i", b, nrm)[:, None] * nrm
    nb = nrm - b_t
    nb /= np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-9)
    ndv = np.clip(np.einsum("ij,ij->i", nb, v), 0.0, 1.0)
    nd = nrm - s["diffuse_bump"][:, None] * b_t
    nd /= np.maximum(np.linalg.norm(nd, axis=1, keepdims=True), 1e-9)
    ndv_d = np.clip(np.einsum("ij,ij->i", nd, v), 0.0, 1.0)
    wrap = s["wrap"]
    diffuse = np.clip((ndv_d + wrap) / (1.0 + wrap), 0.0, 1.0)
    # The light sits on the camera: distance falloff times the spot profile of the light guide.
    axis = g.world_to_camera[2, :3].astype(np.float32)
    cos_axis = np.clip(-(v @ axis), 0.0, 1.0)
    light = light_falloff(dist, app.light_reference_mm) * cos_axis**6.0
    # Normalised Blinn-Phong: the peak grows with the shininess, as on a wet surface.
    spec = s["specular"] * (s["shininess"] + 8.0) / 8.0 * ndv ** s["shininess"] + s["sheen"] * ndv**6
    spec *= np.clip(ndv0 * 3.0, 0.0, 1.0)  # no highlights on silhouettes of the smooth mesh
    rad = light[:, None] * (s["albedo"] * diffuse[:, None] + spec[:, None] * np.array([1.0, 0.97, 0.92], np.float32))

    def full(a, channels=0):
        out = np.zeros((h * w, channels) if channels else h * w, np.float32)
        out[idx] = a
        return out.reshape((h, w, channels) if channels else (h, w))

    albedo_img = full(s["albedo"], 3)
    shading_img = full(light * diffuse)
    spec_img = full(light * spec)
    radiance = full(rad, 3)

    # Camera: lens vignetting, exposure, filmic shoulder, sRGB, blur, noise, mask.
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx + 0.5 - w / 2) ** 2 + (yy + 0.5 - h / 2) ** 2) / (0.25 * (w * w + h * h))
    x = radiance * (1.0 - opt.vignetting * r2)[..., None] * (2.0 * app.exposure)
    white = 4.0
    x = x * (1.0 + x / (white * white)) / (1.0 + x)
    img = linear_to_srgb(x)
    # The camera's colour processing: a mild saturation boost, as endoscope video has.
    grey = img @ np.array([0.299, 0.587, 0.114], np.float32)
    img = grey[..., None] + opt.saturation * (img - grey[..., None])
    if opt.blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), opt.blur_px)
    if opt.noise > 0:
        rng = np.random.default_rng(seed)
        lum_noise = rng.normal(0.0, 1.0, (h, w, 1)).astype(np.float32)
        chroma = rng.normal(0.0, 0.4, (h, w, 3)).astype(np.float32)
        img = img + opt.noise * (lum_noise + chroma) * np.sqrt(np.clip(img, 0.05, 1.0))
    label = g.labels()
    if opt.mask:
        m = circular_mask(h, w, opt.mask_radius)
        img *= m[..., None]
        label[m < 0.5] = LABEL_BACKGROUND
    image = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return RealFrame(image=image, label=label, albedo=albedo_img, shading=shading_img, specular=spec_img, radiance=radiance)


# --- label files -----------------------------------------------------------------------------------


def write_label(path: str | os.PathLike, label: np.ndarray) -> None:
    """Palette PNG: array values are the class indices, viewers show :data:`LABEL_PALETTE`."""
    import io

    from PIL import Image

    from sim2real.fileio import atomic_write_bytes

    pal = np.zeros((256, 3), np.uint8)
    for i, c in enumerate(CLASSES):
        pal[i] = LABEL_PALETTE[c]
    pal[LABEL_BACKGROUND] = LABEL_PALETTE["background"]
    im = Image.fromarray(np.ascontiguousarray(label.astype(np.uint8)), mode="P")
    im.putpalette(pal.reshape(-1).tolist())
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


# --- datasets: many frames, a process pool, deterministic per frame --------------------------------

_WORKER: dict = {}


def _init_worker(scene_dirs: list[str], appearances: list[dict], options: dict) -> None:
    from sim2real.threads import single_thread_worker

    single_thread_worker()
    _WORKER.clear()
    _WORKER["dirs"] = scene_dirs
    _WORKER["appearances"] = [Appearance(**{k: tuple(v) if isinstance(v, list) else v for k, v in a.items()}) for a in appearances]
    _WORKER["options"] = RenderOptions(**options)
    _WORKER["scenes"] = {}


def _worker_scene(k: int):
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.scene import Scene

    if k not in _WORKER["scenes"]:
        scene = Scene.load(_WORKER["dirs"][k])
        _WORKER["scenes"][k] = (RayCaster(scene), SceneMaterial(scene, _WORKER["appearances"][k]))
    return _WORKER["scenes"][k]


def _render_job(job) -> str:
    from sim2real.fileio import atomic_write_image

    k, camera, seed, image_path, label_path = job
    caster, material = _worker_scene(k)
    frame = render_frame(caster.render(camera), material, _WORKER["options"], seed)
    write_label(label_path, frame.label)
    atomic_write_image(image_path, frame.image)
    return image_path


def run_jobs(scene_dirs: Sequence[str], appearances: Sequence[Appearance], options: RenderOptions, jobs: list,
             workers: int | None = None, progress: bool = True, desc: str = "realdomain") -> None:
    """Render ``jobs`` = [(scene index, camera, noise seed, image path, label path)] with a process
    pool (one Embree ray caster + materials per scene and worker); output does not depend on
    ``workers``."""
    import multiprocessing as mp

    from tqdm import tqdm

    workers = max(1, min(len(jobs), workers or os.cpu_count() or 1))
    initargs = ([str(d) for d in scene_dirs], [a.to_json() for a in appearances], options.to_json())
    bar = tqdm(total=len(jobs), desc=desc, unit="frame", disable=not progress)
    try:
        if workers == 1:
            _init_worker(*initargs)
            for job in jobs:
                _render_job(job)
                bar.update()
        else:
            with mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=initargs) as pool:
                for _ in pool.imap_unordered(_render_job, jobs, chunksize=1):
                    bar.update()
    finally:
        bar.close()


def _camera_json(camera) -> dict:
    return {"K": camera.K.tolist(), "world_to_camera": camera.world_to_camera.tolist()}


def make_real_domain(
    scene_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    images: int,
    sequences: int = 0,
    frames: int = 100,
    seed: int = 0,
    height: int = 256,
    width: int = 512,
    fov_x_deg: float = 75.0,
    options: RenderOptions | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> dict:
    """Render the stand-in real domain into the new folder ``out`` and return its manifest.

    Layout::

        OUT/images/000000.png           random views (scene k % S for image k)
        OUT/labels/000000.png           class index per pixel (palette PNG, 255 = background)
        OUT/sequences/000/images/...    consecutive frames along a smooth camera path
        OUT/sequences/000/labels/...
        OUT/sequences/000/trajectory.txt
        OUT/manifest.json               seeds, parameters, appearance of each scene, every camera
    """
    from sim2real.fileio import atomic_write_json, prepare_output_dir
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.camera import check_size
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory, sample_poses

    if int(images) != images or images < 1:
        raise UserError(f"the number of images must be at least 1, got {images}")
    if int(sequences) != sequences or sequences < 0:
        raise UserError(f"the number of sequences must be 0 or more, got {sequences}")
    if sequences and frames < 2:
        raise UserError(f"a sequence needs at least 2 frames, got {frames}")
    if not scene_dirs:
        raise UserError("give at least one scene directory")
    check_size(height, width)
    if not 1.0 <= fov_x_deg <= 170.0:
        raise UserError(f"field of view must be in [1, 170] degrees, got {fov_x_deg}")
    opt = options or RenderOptions()
    opt = RenderOptions(**{**opt.to_json(), "height": int(height), "width": int(width), "fov_x_deg": float(fov_x_deg)})
    for d in scene_dirs:
        if not Path(d).exists():
            raise UserError(f"scene directory {d} does not exist")
    scenes = [Scene.load(d) for d in scene_dirs]  # fails with a UserError before anything is written
    out = prepare_output_dir(out)
    dirs = [str(Path(d).resolve()) for d in scene_dirs]
    appearances = [Appearance.sample(derive_seed(seed, _APPEARANCE, k)) for k in range(len(scenes))]
    casters = [RayCaster(s) for s in scenes]

    jobs, frame_entries = [], []
    for i in range(images):
        k = i % len(scenes)
        pose_seed = derive_seed(seed, _POSE, i)
        cam = sample_poses(casters[k], 1, height, width, fov_x_deg, seed=pose_seed)[0]
        name = f"{i:06d}.png"
        noise_seed = derive_seed(seed, _FRAME, i)
        jobs.append((k, cam, noise_seed, str(out / "images" / name), str(out / "labels" / name)))
        frame_entries.append({"image": f"images/{name}", "label": f"labels/{name}", "scene": k,
                              "pose_seed": pose_seed, "noise_seed": noise_seed, **_camera_json(cam)})
    seq_entries = []
    for j in range(sequences):
        k = j % len(scenes)
        traj_seed = derive_seed(seed, _TRAJECTORY, j)
        traj = make_trajectory(casters[k], frames, height, width, fov_x_deg, seed=traj_seed)
        sdir = out / "sequences" / f"{j:03d}"
        traj.save(sdir / "trajectory.txt")
        entries = []
        for t, cam in enumerate(traj.cameras):
            name = f"{t:06d}.png"
            noise_seed = derive_seed(seed, _SEQUENCE_FRAME, j, t)
            jobs.append((k, cam, noise_seed, str(sdir / "images" / name), str(sdir / "labels" / name)))
            entries.append({"image": f"images/{name}", "label": f"labels/{name}", "noise_seed": noise_seed,
                            **_camera_json(cam)})
        seq_entries.append({"dir": f"sequences/{j:03d}", "scene": k, "trajectory_seed": traj_seed,
                            "trajectory": f"sequences/{j:03d}/trajectory.txt", "fps": traj.fps, "frames": entries})
    del casters

    run_jobs(dirs, appearances, opt, jobs, workers=workers, progress=progress)

    pal = {c: list(LABEL_PALETTE[c]) for c in CLASSES}
    manifest = {
        "format": FORMAT,
        "generator": "sim2real.render.realdomain",
        "seed": int(seed),
        "images": int(images),
        "sequences": int(sequences),
        "frames_per_sequence": int(frames) if sequences else 0,
        "render": opt.to_json(),
        "labels": {"classes": list(CLASSES), "background": LABEL_BACKGROUND,
                   "palette": {**pal, "background": list(LABEL_PALETTE["background"])}},
        "scenes": [
            {"dir": d, "name": s.name, "scene_seed": s.metadata.get("seed"), "appearance": a.to_json()}
            for d, s, a in zip(dirs, scenes, appearances)
        ],
        "frames": frame_entries,
        "sequence_list": seq_entries,
    }
    atomic_write_json(out / "manifest.json", manifest)
    return manifest
