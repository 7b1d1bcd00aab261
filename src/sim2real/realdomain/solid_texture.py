"""Solid (3D) texture fields for the procedural real domain: value noise, fBm and cellular noise.

Every field is a pure function of a 3D point in an object's local frame (mm) and a seed, so a
surface point looks the same from every view. All evaluation is vectorised numpy over (N, 3)
arrays of points; nothing loops over pixels.

* :class:`Noise` - value noise on a periodic random lattice (64^3 values, smoothstep
  interpolation) with its analytic gradient, and fBm over randomly rotated octaves. Octaves whose
  wavelength is below about two pixel footprints fade out (pre-filtering, so detail does not
  alias or flicker when the camera moves away).
* :class:`CellField` - Worley / cellular noise: one jittered feature point per cubic cell, kept
  only for cells near the object's surface, searched with a k-d tree. A query returns the two
  nearest feature points, their ids, and the exact distance to the Voronoi face between them
  (the bisector plane), which gives cell edges (lobule boundaries, capillary meshes) of constant
  width in millimetres.

Branching vessel trees on a surface: :mod:`sim2real.realdomain.vessel_tree`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

_ZERO3 = np.zeros(3, np.float32)
_M1 = np.uint32(0x7FEB352D)
_M2 = np.uint32(0x846CA68B)


def hash_u32(x: np.ndarray, seed: int = 0) -> np.ndarray:
    """A well-mixed uint32 hash ("lowbias32") of integer array ``x`` and ``seed``."""
    h = (np.asarray(x).astype(np.uint64) & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    h ^= np.uint32((seed * 0x9E3779B9) & 0xFFFFFFFF)
    with np.errstate(over="ignore"):
        h ^= h >> np.uint32(16)
        h *= _M1
        h ^= h >> np.uint32(15)
        h *= _M2
        h ^= h >> np.uint32(16)
    return h


def hash_unit(x: np.ndarray, seed: int = 0) -> np.ndarray:
    """Uniform floats in [0, 1) (float32) hashed from integers ``x``."""
    return (hash_u32(x, seed) >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


class Noise:
    """Value noise and fBm (see module docstring). Same seed, same field."""

    SIZE = 64
    MAX_OCTAVES = 10

    def __init__(self, seed: int):
        rng = np.random.default_rng(seed)
        s = self.SIZE
        table = rng.uniform(-1.0, 1.0, (s, s, s)).astype(np.float32)
        # Padded by one periodic layer per axis, so corner i + 1 needs no wrap-around.
        self.table = np.pad(table, ((0, 1), (0, 1), (0, 1)), mode="wrap").reshape(-1)
        self.rotations = np.stack([random_rotation(rng) for _ in range(self.MAX_OCTAVES)]).astype(np.float32)
        self.offsets = rng.uniform(0.0, s, size=(self.MAX_OCTAVES, 3)).astype(np.float32)

    def value(self, p: np.ndarray, grad: bool = False):
        """Noise in about [-1, 1] at lattice coordinates ``p`` (N, 3); with ``grad`` also d/dp."""
        p = np.asarray(p, dtype=np.float32)
        fl = np.floor(p)
        f = p - fl
        i = fl.astype(np.int32) & np.int32(self.SIZE - 1)
        s1 = self.SIZE + 1
        base = (i[:, 0] * s1 + i[:, 1]) * s1 + i[:, 2]
        t = self.table
        dx, dy = s1 * s1, s1
        c000 = t[base]
        c001 = t[base + 1]
        c010 = t[base + dy]
        c011 = t[base + (dy + 1)]
        c100 = t[base + dx]
        c101 = t[base + (dx + 1)]
        c110 = t[base + (dx + dy)]
        c111 = t[base + (dx + dy + 1)]
        u = f * f * (3.0 - 2.0 * f)
        ux, uy, uz = u[:, 0], u[:, 1], u[:, 2]
        # Interpolate along z, then y, then x.
        e00 = c001 - c000
        e01 = c011 - c010
        e10 = c101 - c100
        e11 = c111 - c110
        c00 = c000 + uz * e00
        c01 = c010 + uz * e01
        c10 = c100 + uz * e10
        c11 = c110 + uz * e11
        c0 = c00 + uy * (c01 - c00)
        c1 = c10 + uy * (c11 - c10)
        n = c0 + ux * (c1 - c0)
        if not grad:
            return n
        du = 6.0 * f * (1.0 - f)
        gx = du[:, 0] * (c1 - c0)
        gy = du[:, 1] * ((c01 - c00) + ux * ((c11 - c10) - (c01 - c00)))
        d0 = e00 + uy * (e01 - e00)
        d1 = e10 + uy * (e11 - e10)
        gz = du[:, 2] * (d0 + ux * (d1 - d0))
        return n, np.stack([gx, gy, gz], axis=1)

    @staticmethod
    def _affine(p: np.ndarray, m: np.ndarray, off: np.ndarray) -> np.ndarray:
        """p @ m.T + off for (N, 3) float32, written out (numpy's small matmul is slow)."""
        out = np.empty_like(p)
        for r in range(3):
            out[:, r] = p[:, 0] * m[r, 0] + p[:, 1] * m[r, 1] + p[:, 2] * m[r, 2] + off[r]
        return out

    def fbm(
        self,
        p: np.ndarray,
        scale: float,
        octaves: int = 4,
        gain: float = 0.5,
        lacunarity: float = 2.03,
        footprint: np.ndarray | None = None,
        grad: bool = False,
        first_octave: int = 0,
    ):
        """Fractal sum of rotated octaves; ``scale`` is the largest wavelength in mm.

        Returns values normalised to roughly unit standard deviation (and the gradient per mm
        with ``grad``). ``footprint`` (N,) in mm per pixel fades out octaves that are too fine to
        be resolved."""
        p = np.asarray(p, dtype=np.float32)
        total = np.zeros(len(p), np.float32)
        g_total = np.zeros((len(p), 3), np.float32) if grad else None
        amp, freq, norm = 1.0, 1.0 / scale, 0.0
        for o in range(first_octave, first_octave + octaves):
            k = o % self.MAX_OCTAVES
            q = self._affine(p, self.rotations[k] * np.float32(freq), self.offsets[k])
            w = np.float32(amp)
            if footprint is not None:
                # Wavelength / footprint: full weight above 4 px, none below 2 px.
                w = w * np.clip((1.0 / freq) / np.maximum(footprint, 1e-6) * 0.5 - 1.0, 0.0, 1.0).astype(np.float32)
                if not np.any(w):
                    norm += amp * amp
                    amp *= gain
                    freq *= lacunarity
                    continue
            if grad:
                n, g = self.value(q, grad=True)
                total += w * n
                g_total += np.reshape(w * np.float32(freq), (-1, 1)) * self._affine(g, self.rotations[k].T, _ZERO3)
            else:
                total += w * self.value(q)
            norm += amp * amp
            amp *= gain
            freq *= lacunarity
        s = np.float32(1.0 / (0.36 * np.sqrt(norm)))  # value noise has a standard deviation of ~0.36
        total *= s
        if grad:
            g_total *= s
            return total, g_total
        return total

    def vector(self, p: np.ndarray, scale: float, octaves: int = 2, footprint=None) -> np.ndarray:
        """A 3-vector field (N, 3) of three decorrelated fBm fields (for domain warping)."""
        return np.stack(
            [self.fbm(p, scale, octaves, footprint=footprint, first_octave=3 * c) for c in range(3)], axis=1
        )


@dataclass
class CellQuery:
    """Result of :meth:`CellField.query` for N points."""

    f1: np.ndarray  # (N,) distance to the nearest feature point (mm)
    f2: np.ndarray  # (N,) distance to the second nearest
    id1: np.ndarray  # (N,) uint32 random id of the nearest feature point's cell
    id2: np.ndarray  # (N,) uint32 id of the second nearest
    edge: np.ndarray  # (N,) distance to the Voronoi face between the two (mm), >= 0
    edge_dir: np.ndarray  # (N, 3) unit gradient of ``edge`` (points away from the face, into cell 1)
    delta1: np.ndarray  # (N, 3) query point minus the nearest feature point
    delta2: np.ndarray  # (N, 3) query point minus the second nearest

    def edge_id(self) -> np.ndarray:
        """A symmetric uint32 id of the Voronoi face (the same from both of its cells)."""
        a = np.minimum(self.id1, self.id2).astype(np.uint64)
        b = np.maximum(self.id1, self.id2).astype(np.uint64)
        return hash_u32((a * np.uint64(2654435761) + b) & np.uint64(0xFFFFFFFF), 17)


def surface_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float, seed: int, max_samples: int = 600_000) -> np.ndarray:
    """Random points on a triangle mesh, area-weighted, about one per ``spacing``^2 mm^2 (at least
    every vertex too)."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n = int(min(max_samples, max(16, area.sum() / spacing**2)))
    cdf = np.cumsum(area)
    face = np.minimum(np.searchsorted(cdf, rng.uniform(0, cdf[-1], n)), len(faces) - 1)
    r1, r2 = rng.uniform(size=(2, n))
    s = np.sqrt(r1)
    b0, b1, b2 = 1 - s, s * (1 - r2), s * r2
    pts = b0[:, None] * tri[face, 0] + b1[:, None] * tri[face, 1] + b2[:, None] * tri[face, 2]
    return np.vstack([pts, vertices])


_KEY_BIAS = 1 << 20


def cell_keys(cells: np.ndarray) -> np.ndarray:
    """One int64 key per integer cell (N, 3): 21 bits per axis, biased to be non-negative."""
    c = cells.astype(np.int64) + _KEY_BIAS
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


def _keys_to_cells(keys: np.ndarray) -> np.ndarray:
    mask = (1 << 21) - 1
    return np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], axis=1) - _KEY_BIAS


class CellField:
    """Cellular (Worley) noise near a surface; see the module docstring.

    ``samples`` are points on the surface (local frame, mm), ``cell`` the cell size (mm),
    ``reach`` how far (mm) from the surface queries may land (e.g. after domain warping).
    Jitter is a hash of the cell coordinates and the seed: a cell's feature point does not
    depend on which samples found the cell."""

    def __init__(self, samples: np.ndarray, cell: float, seed: int, reach: float = 0.0, jitter: float = 0.9):
        self.cell = float(cell)
        cells = np.unique(cell_keys(np.floor(samples / cell)))
        ring = 1 + int(np.ceil(reach / cell))
        r = np.arange(-ring, ring + 1)
        offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        offs = offs[np.linalg.norm(offs, axis=1) <= ring + 0.75]
        base = _keys_to_cells(cells)
        keys = np.unique(np.concatenate([cell_keys(base + o) for o in offs]))
        cc = _keys_to_cells(keys).astype(np.float64)
        h = keys ^ (keys >> 29)
        jit = np.stack([hash_unit(h, seed * 3 + a) for a in range(3)], axis=1).astype(np.float64)
        self.points = (cc + 0.5 + jitter * (jit - 0.5)) * cell
        self.ids = hash_u32(h, seed * 3 + 7)
        self.tree = cKDTree(self.points)

    def query(self, q: np.ndarray) -> CellQuery:
        q = np.asarray(q, dtype=np.float64)
        d, i = self.tree.query(q, k=2)
        c1, c2 = self.points[i[:, 0]], self.points[i[:, 1]]
        diff = c1 - c2
        length = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
        f1, f2 = d[:, 0], d[:, 1]
        edge = np.maximum((f2 * f2 - f1 * f1) / (2.0 * length), 0.0)
        return CellQuery(
            f1=f1.astype(np.float32),
            f2=f2.astype(np.float32),
            id1=self.ids[i[:, 0]],
            id2=self.ids[i[:, 1]],
            edge=edge.astype(np.float32),
            edge_dir=(diff / length[:, None]).astype(np.float32),
            delta1=(q - c1).astype(np.float32),
            delta2=(q - c2).astype(np.float32),
        )


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def line_profile(distance: np.ndarray, radius: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """Coverage of a line of half-width ``radius`` (mm) at ``distance`` from its axis, pre-filtered
    by the pixel footprint (mm): a line thinner than a pixel gets wider and fainter, keeping its
    integrated darkness, so it neither aliases nor vanishes with distance."""
    eff = np.sqrt(radius * radius + (0.5 * footprint) ** 2)
    return (radius / eff) * np.exp(-((distance / eff) ** 2) * 1.6)
