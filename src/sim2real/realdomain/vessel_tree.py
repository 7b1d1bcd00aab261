"""Branching vessel trees on an object's surface for the procedural real domain.

:class:`VesselTree` is precomputed once per object: a random spanning forest over blue-noise
surface nodes (:func:`blue_noise`), calibres from Murray's law (radius ~ flow^(1/3)), queried as
the distance to the nearest segment through a k-d tree. Like the fields of
:mod:`sim2real.realdomain.solid_texture`, it lives in the object's local frame (mm), so a vessel
looks the same from every view.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from sim2real.realdomain.solid_texture import cell_keys, hash_u32


def blue_noise(samples: np.ndarray, spacing: float, seed: int) -> np.ndarray:
    """A subset of ``samples`` about ``spacing`` apart: the first sample (in a seeded random order)
    of every cubic cell of size ``spacing``, then points closer than half the spacing dropped."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(samples))
    keys = cell_keys(np.floor(samples[order] / spacing))
    _, first = np.unique(keys, return_index=True)
    pts = samples[order[np.sort(first)]]
    pairs = cKDTree(pts).query_pairs(0.5 * spacing, output_type="ndarray")
    if len(pairs):
        drop = np.zeros(len(pts), bool)
        drop[np.maximum(pairs[:, 0], pairs[:, 1])] = True
        pts = pts[~drop]
    return pts


class VesselTree:
    """Branching vessel trees on a surface, precomputed once per object.

    Nodes are blue-noise points on the surface (``spacing`` apart). A random spanning tree joins
    neighbouring nodes (minimum spanning tree of edge lengths times random factors, so paths
    meander); cutting its longest-weighted edges splits it into ``roots`` trees, each rooted at a
    random node. An edge's flow is the number of nodes downstream of it; its radius follows
    Murray's law, ``r = r_leaf * flow^(1/3)`` capped at ``r_max``, so calibres taper from trunks to
    twigs. Edges with a flow below ``prune`` are dropped (this sets the vessel density).
    Queries return the distance from a point to the nearest kept segment (exact distance to a
    segment found through points sampled along all segments), that segment's radius and the id
    of its tree."""

    def __init__(self, samples: np.ndarray, spacing: float, seed: int, r_leaf: float, r_max: float,
                 prune: int = 4, roots: int | None = None, exponent: float = 3.0, smooth: int = 3):
        rng = np.random.default_rng(seed)
        nodes = blue_noise(samples, spacing, seed)
        n = len(nodes)
        self.nodes = nodes
        pairs = cKDTree(nodes).query_pairs(1.9 * spacing, output_type="ndarray") if n > 1 else np.zeros((0, 2), int)
        if len(pairs) == 0:
            self._empty()
            return
        length = np.linalg.norm(nodes[pairs[:, 0]] - nodes[pairs[:, 1]], axis=1)
        weight = length * rng.uniform(0.5, 1.5, len(pairs)) + 1e-6
        mst = minimum_spanning_tree(coo_matrix((weight, (pairs[:, 0], pairs[:, 1])), shape=(n, n))).tocoo()
        ea, eb, ew = mst.row, mst.col, mst.data
        # Split into several trees: drop the heaviest edges.
        roots = roots or max(1, n // 400)
        if roots > 1 and len(ew) > roots:
            keep = np.argsort(ew)[: len(ew) - (roots - 1)]
            ea, eb, ew = ea[keep], eb[keep], ew[keep]
        forest = coo_matrix((np.ones(len(ea)), (ea, eb)), shape=(n, n)).tocsr()
        forest = forest + forest.T
        ncomp, comp = connected_components(forest, directed=False)
        parent = np.full(n, -1, np.int64)
        order_all = []
        for c in range(ncomp):
            members = np.nonzero(comp == c)[0]
            root = members[rng.integers(len(members))]
            order, pred = breadth_first_order(forest, root, directed=False, return_predecessors=True)
            parent[order[1:]] = pred[order[1:]]
            order_all.append(order)
        # Flow = nodes downstream, accumulated from the leaves up (reverse BFS order).
        flow = np.ones(n, np.int64)
        for order in order_all:
            for v in order[:0:-1]:
                flow[parent[v]] += flow[v]
        # Smooth the paths: pull each node towards the mean of its tree neighbours (a few Jacobi
        # steps of Laplacian smoothing), so vessels curve instead of zig-zagging between nodes.
        child = np.nonzero(parent >= 0)[0]
        deg = np.bincount(np.concatenate([child, parent[child]]), minlength=n).astype(np.float64)
        for _ in range(smooth):
            acc = np.zeros_like(nodes)
            np.add.at(acc, child, nodes[parent[child]])
            np.add.at(acc, parent[child], nodes[child])
            has = deg > 0
            nodes = nodes.copy()
            nodes[has] = 0.5 * nodes[has] + 0.5 * acc[has] / deg[has, None]
        self.nodes = nodes
        f = flow[child]
        keep = f >= prune
        child = child[keep]
        f = f[keep]
        if len(child) == 0:
            self._empty()
            return
        self.a = nodes[child]
        self.b = nodes[parent[child]]
        self.radius = np.minimum(r_max, r_leaf * (f - prune + 1.0) ** (1.0 / exponent)).astype(np.float32)
        self.flow = f
        self.ids = hash_u32(comp[child], seed)  # one id per tree: colour and depth stay along a vessel
        # Points along every kept segment, every quarter spacing, to find the nearest segment.
        seg_len = np.linalg.norm(self.b - self.a, axis=1)
        steps = np.maximum(1, np.ceil(seg_len / (0.25 * spacing)).astype(np.int64))
        seg = np.repeat(np.arange(len(child)), steps + 1)
        t = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in steps])
        pts = self.a[seg] + (self.b[seg] - self.a[seg]) * t[:, None]
        self._seg = seg
        self._tree = cKDTree(pts)

    def _empty(self) -> None:
        self.a = self.b = np.zeros((0, 3))
        self.radius = np.zeros(0, np.float32)
        self.flow = np.zeros(0, np.int64)
        self.ids = np.zeros(0, np.uint32)
        self._tree = None

    def __len__(self) -> int:
        return len(self.radius)

    def query(self, q: np.ndarray, k: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Distance (mm) to the nearest kept segment, its radius and its tree's uint32 id, for (N, 3)."""
        q = np.asarray(q, dtype=np.float64)
        if self._tree is None or len(q) == 0:
            return np.full(len(q), np.inf, np.float32), np.zeros(len(q), np.float32), np.zeros(len(q), np.uint32)
        _, i = self._tree.query(q, k=k)
        i = i.reshape(len(q), k)
        best = np.full(len(q), np.inf)
        best_seg = np.zeros(len(q), np.int64)
        for j in range(k):
            s = self._seg[i[:, j]]
            a, b = self.a[s], self.b[s]
            ab = b - a
            t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0.0, 1.0)
            d = np.linalg.norm(q - (a + ab * t[:, None]), axis=1)
            better = d < best
            best = np.where(better, d, best)
            best_seg = np.where(better, s, best_seg)
        return best.astype(np.float32), self.radius[best_seg], self.ids[best_seg]
