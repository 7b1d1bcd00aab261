"""Materials of the stand-in real domain: solid textures of the surface point, per class.

Appearance is defined in 3D: every material is a solid texture of the surface point in its
object's local frame (``point - object bounding-box minimum``, mm; see
:mod:`sim2real.realdomain.solid_texture`), so a point has the same albedo in every view. Materials:

* abdominal wall: pinkish white, milky patches and a reddish blush, faint muscle striation
  showing through, branching red vessel trees whose calibres taper from trunks to twigs
  (:class:`~sim2real.realdomain.vessel_tree.VesselTree`) and a faint capillary mesh (edges of
  domain-warped Voronoi cells); wrapped diffuse for a translucent look;
* liver: dark red-brown, glossy, fine mottling and a faint lobular (cellular) pattern;
* fat (and stomach, which the procedural scenes put in the fat object): yellow-orange lobules of
  varying tint with reddish septa and thin vessels between them, each lobule bulging (bump map);
* gallbladder: greenish, glossy, a few vessels; ligament: whitish, fibrous streaks, fat patches;
* any other class (stomach, kidney, instrument, a user's own): a neutral material, the class
  table's a_ref colour with a mild mottling, a little gloss and a fine bump
  (:func:`material_default`).

Each material returns a :class:`Surface` (albedo, bump gradient, gloss); the shading is in
:mod:`sim2real.realdomain.shading`.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sim2real.realdomain.appearance import Appearance, derive_seed, srgb_to_linear
from sim2real.realdomain.solid_texture import (
    CellField,
    Noise,
    hash_unit,
    line_profile,
    smoothstep,
    surface_samples,
)
from sim2real.realdomain.vessel_tree import VesselTree


def _stable(text: str) -> int:
    """A hash of a string that is the same in every process (unlike ``hash``)."""
    return zlib.crc32(text.encode())


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


def material_default(obj: _Object, app: Appearance, p: np.ndarray, n: np.ndarray, fp: np.ndarray,
                     colour=(0.6, 0.45, 0.45)) -> Surface:
    """A neutral material for a class without its own: ``colour`` (sRGB in [0, 1], the class's
    a_ref colour) with a mild low-frequency mottling, a fine bump and a moderate gloss."""
    N = len(p)
    nz = obj.noise
    c = _full(N, colour) * (1.0 + 0.1 * nz.fbm(p, 10.0, 3, footprint=fp))[:, None]
    _, g = nz.fbm(p, 3.0, 2, footprint=fp, grad=True, first_octave=5)
    return Surface(np.clip(c, 0, 1), 0.08 * g, 0.05 * app.gloss, 60.0, 0.2, sheen=0.04)


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
            cls = self.scene.objects[int(k)].cls
            if cls in MATERIALS:
                s = MATERIALS[cls](obj, self.appearance, p, normals[sel], footprint[sel])
            else:
                s = material_default(obj, self.appearance, p, normals[sel], footprint[sel],
                                     self.scene.class_table[cls].a_ref)
            out["albedo"][sel] = s.albedo
            out["bump"][sel] = s.bump
            out["specular"][sel] = s.specular
            out["shininess"][sel] = s.shininess
            out["wrap"][sel] = s.wrap
            out["sheen"][sel] = s.sheen
            out["diffuse_bump"][sel] = s.diffuse_bump
        return out
