"""Vectorised ray casting of a scene into G-buffers, with Embree (embreex) called directly.

One Embree geometry per scene object, so the geometry id is the object id. All rays of a
view go to Embree in one call; nothing loops over pixels in Python, and trimesh's
pure-numpy ray caster is never used (it took 57 s for 2,000 rays here).
Embree runs one core per process: :func:`render_views` uses a process pool for many views. The
workers get the scene as a :class:`SceneGeometry` (plain arrays), so they never import trimesh
(1.2 s of a worker's start here) nor load the meshes again.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Sequence

import numpy as np
from tqdm import tqdm

from sim2real.errors import UserError
from sim2real.fileio import fsync_files
from sim2real.pool import WorkerPool
from sim2real.render.gbuffer import GBuffer
from sim2real.render.reference import save_preview
from sim2real.scene.camera import Camera, pixel_centres
from sim2real.scene.scene import Scene
from sim2real.threads import worker_count

if TYPE_CHECKING:
    from sim2real.scene.classes import ClassTable

_MISS = 1e30


def _embree():
    try:  # imported here, not at the top: a broken Embree install gets one line, not a traceback at import
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as e:  # pragma: no cover - exercised only on broken installs
        raise UserError(
            f"Embree is not available ({e}); install it with 'pip install embreex' "
            "(sim2real does not fall back to a slow Python ray caster)"
        ) from None
    return rtcore_scene, TriangleMesh


# Directions for inside/outside tests: the 12 vertices of an icosahedron, slightly rotated so
# that no direction is parallel to a mesh axis.
_PHI = (1 + 5**0.5) / 2
_DIRS = np.array(
    [[-1, _PHI, 0], [1, _PHI, 0], [-1, -_PHI, 0], [1, -_PHI, 0], [0, -1, _PHI], [0, 1, _PHI],
     [0, -1, -_PHI], [0, 1, -_PHI], [_PHI, 0, -1], [_PHI, 0, 1], [-_PHI, 0, -1], [-_PHI, 0, 1]],
    dtype=np.float64,
)
_DIRS = _DIRS @ np.array([[0.99, -0.1, 0.05], [0.1, 0.99, -0.03], [-0.05, 0.03, 0.998]]).T
_DIRS /= np.linalg.norm(_DIRS, axis=1, keepdims=True)


@dataclass(frozen=True)
class SceneGeometry:
    """What the ray caster needs of a scene, as plain arrays (cheap to send to worker processes).

    Per object, in object-id order: ``vertices`` (V, 3) float64 mm, ``faces`` (F, 3) int64,
    ``face_normals`` (F, 3) float32 (outward unit normals) and ``vertex_normals`` (V, 3) float32
    (the mesh's own smooth normals where the scene stores them, else area-weighted; unit)."""

    classes: tuple[str, ...]
    vertices: tuple[np.ndarray, ...]
    faces: tuple[np.ndarray, ...]
    face_normals: tuple[np.ndarray, ...]
    vertex_normals: tuple[np.ndarray, ...]
    class_table: "ClassTable | None" = None

    @classmethod
    def of(cls, scene: "Scene") -> "SceneGeometry":
        verts = tuple(np.asarray(o.mesh.vertices, dtype=np.float64) for o in scene.objects)
        faces = tuple(np.asarray(o.mesh.faces, dtype=np.int64) for o in scene.objects)
        normals = tuple(
            _unit(np.asarray(o.mesh.vertex_normals, np.float64)).astype(np.float32) if o.own_normals
            else _smooth_normals(v, f).astype(np.float32)
            for o, v, f in zip(scene.objects, verts, faces))
        return cls(
            classes=tuple(scene.classes),
            vertices=verts,
            faces=faces,
            face_normals=tuple(np.asarray(o.mesh.face_normals, np.float32) for o in scene.objects),
            vertex_normals=normals,
            class_table=scene.class_table,
        )


class RayCaster:
    """Casts rays against a :class:`Scene` (or its :class:`SceneGeometry`: then ``scene`` is None).
    Build once per process, reuse for many views."""

    def __init__(self, scene: "Scene | SceneGeometry"):
        rtcore_scene, TriangleMesh = _embree()
        geometry = scene if isinstance(scene, SceneGeometry) else SceneGeometry.of(scene)
        self.scene = None if scene is geometry else scene
        self.geometry = geometry
        self.classes = geometry.classes
        self.skipped_background = 0
        """Random poses drawn again for too much background (:mod:`sim2real.scene.trajectory`)."""
        self._embree = rtcore_scene.EmbreeScene()
        faces_all, face_offset, n_verts, n_faces = [], [], 0, 0
        for verts, faces in zip(geometry.vertices, geometry.faces):
            TriangleMesh(self._embree, verts[faces].astype(np.float32))
            face_offset.append(n_faces)
            faces_all.append(faces + n_verts)
            n_verts += len(verts)
            n_faces += len(faces)
        # All objects' faces and vertex normals in one table; object k's faces start at offset[k].
        self._all_faces = np.concatenate(faces_all)
        self._all_normals = np.concatenate(geometry.vertex_normals)
        self._face_offset = np.array(face_offset, dtype=np.int64)
        self._face_normals = np.concatenate(geometry.face_normals)
        # Embree builds its BVH on the first query: do it now, not inside the first view.
        self.intersect(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        """First hits of rays (N, 3). Returns ``object`` (N,) int (-1 = miss), ``prim``, ``u``,
        ``v`` (barycentrics of vertices 1 and 2), ``face`` (row of the all-object face table; 0 on a
        miss), ``t`` (ray parameter; distance for unit
        directions) and ``facing`` (dot of the geometric normal and the direction; > 0 means
        the ray hit the back of a face, i.e. it left a closed object)."""
        o = np.ascontiguousarray(origins, dtype=np.float32).reshape(-1, 3)
        d = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
        if len(o) == 1 and len(d) > 1:
            o = np.ascontiguousarray(np.broadcast_to(o, d.shape))
        r = self._embree.run(o, d, output=1)
        geom = r["geomID"].astype(np.int64)
        hit = geom >= 0
        # Our own outward face normals: Embree 2 and 4 disagree on the sign of Ng.
        face = np.where(hit, self._face_offset[np.maximum(geom, 0)] + r["primID"], 0)
        facing = np.einsum("ij,ij->i", self._face_normals[face], d)
        return {
            "object": np.where(hit, geom, -1),
            "prim": r["primID"].astype(np.int64),
            "face": face,
            "u": r["u"],
            "v": r["v"],
            "t": np.where(hit, r["tfar"], _MISS),
            "facing": np.where(hit, facing, 0.0),
        }

    def render(self, camera: Camera) -> GBuffer:
        """G-buffer of one view (see :mod:`sim2real.render.gbuffer` for keys and units)."""
        h, w = camera.height, camera.width
        d_cam = _camera_directions(camera.K, h, w)  # (H*W, 3) unit, camera frame
        c2w = camera.camera_to_world
        dirs = d_cam @ c2w[:3, :3].T.astype(np.float32)
        origin = c2w[:3, 3]
        hits = self.intersect(origin[None], dirs)
        obj = hits["object"]
        hit = obj >= 0
        t = np.where(hit, hits["t"], 0.0).astype(np.float32)
        points = (origin.astype(np.float32) + dirs * t[:, None]) * hit[:, None]
        # Smooth normals: barycentric blend of the vertex normals of the hit triangle.
        tri = self._all_faces[hits["face"]]
        u, v = hits["u"][:, None], hits["v"][:, None]
        vn = self._all_normals
        n = (1 - u - v) * vn[tri[:, 0]] + u * vn[tri[:, 1]] + v * vn[tri[:, 2]]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        # Face the camera: the light sits on the camera, so normals point towards it.
        n *= np.where(np.einsum("ij,ij->i", n, dirs) > 0, -1.0, 1.0).astype(np.float32)[:, None]
        n *= hit[:, None]
        return GBuffer(
            K=camera.K.astype(np.float64),
            world_to_camera=camera.world_to_camera.astype(np.float64),
            depth=(t * d_cam[:, 2]).reshape(h, w),
            distance=t.reshape(h, w),
            normal=n.astype(np.float32).reshape(h, w, 3),
            object_id=obj.reshape(h, w).astype(np.int16),
            points=points.reshape(h, w, 3),
            classes=self.classes,
            class_table=self.geometry.class_table,
        )

    def background_share(self, camera: Camera, probe: int = 32) -> float:
        """Share of the view's rays that hit nothing (escape through a hole in the scene),
        estimated on a grid of about ``probe`` x ``2 probe`` rays (the view's aspect kept)."""
        h = max(1, min(camera.height, probe))
        w = max(1, round(camera.width * h / camera.height))
        K = camera.K.copy()
        K[0] *= w / camera.width
        K[1] *= h / camera.height
        d = _camera_directions(K, h, w) @ camera.camera_to_world[:3, :3].T.astype(np.float32)
        hits = self.intersect(camera.camera_to_world[:3, 3][None], d)
        return float((hits["object"] < 0).mean())

    # --- inside / outside ----------------------------------------------------------------------

    def containing_object(self, points: np.ndarray) -> np.ndarray:
        """For each point (N, 3): the id of the closed object that contains it, else -1.

        A ray that first meets the back of a face has started inside that object; the
        answer is the majority over 12 directions, which is robust to grazing rays."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = len(points)
        origins = np.repeat(points, len(_DIRS), axis=0)
        dirs = np.tile(_DIRS, (n, 1))
        hits = self.intersect(origins, dirs)
        inside = np.where(hits["facing"] > 0, hits["object"], -1).reshape(n, len(_DIRS))
        out = np.full(n, -1, dtype=np.int64)
        for k in range(len(self.classes)):
            votes = (inside == k).sum(axis=1)
            out[votes > len(_DIRS) // 2] = k
        return out

    def enclosed(self, points: np.ndarray) -> np.ndarray:
        """True for points that the scene closes around: most rays from them hit something."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        origins = np.repeat(points, len(_DIRS), axis=0)
        hits = self.intersect(origins, np.tile(_DIRS, (len(points), 1)))
        misses = (hits["object"] < 0).reshape(len(points), len(_DIRS)).sum(axis=1)
        return misses <= len(_DIRS) // 2

    def free_space(self, points: np.ndarray) -> np.ndarray:
        """True where a camera may be: inside the cavity and outside every organ."""
        ok = self.containing_object(points) < 0
        if "abdominal_wall" in self.classes:
            ok &= self.enclosed(points)
        return ok

    def visible(self, eye: np.ndarray, targets: np.ndarray, object_index: int, tol: float = 1.0) -> np.ndarray:
        """True for targets (N, 3) on object ``object_index`` that ``eye`` sees unobstructed."""
        d = targets - eye
        dist = np.linalg.norm(d, axis=1)
        hits = self.intersect(np.asarray(eye)[None], d / dist[:, None])
        return (hits["object"] == object_index) & (np.abs(hits["t"] - dist) < tol)


@functools.lru_cache(maxsize=8)
def _camera_directions_cached(k_bytes: bytes, h: int, w: int) -> np.ndarray:
    K = np.frombuffer(k_bytes, dtype=np.float64).reshape(3, 3)
    uv = pixel_centres(h, w).reshape(-1, 2)
    d = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ np.linalg.inv(K).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d.astype(np.float32)
    d.setflags(write=False)
    return d


def _camera_directions(K: np.ndarray, h: int, w: int) -> np.ndarray:
    """Unit ray directions through the pixel centres, camera frame, (H*W, 3) float32."""
    return _camera_directions_cached(np.ascontiguousarray(K, dtype=np.float64).tobytes(), h, w)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(n > 1e-20, v / np.maximum(n, 1e-20), np.array([0.0, 0.0, 1.0]))


def _smooth_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit length; arbitrary unit vector for isolated vertices)."""
    fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    vn = np.zeros_like(verts)
    for c in range(3):
        np.add.at(vn, faces[:, c], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    vn = np.where(norm > 1e-20, vn / np.maximum(norm, 1e-20), np.array([0.0, 0.0, 1.0]))
    return vn


def check_camera_region(scene: "Scene", caster: RayCaster | None = None, samples: int = 256, seed: int = 0) -> None:
    """Refuse a camera region that lies inside an organ or outside the abdominal wall."""
    caster = caster or RayCaster(scene)
    pts = scene.camera_region.sample(np.random.default_rng(seed), samples)
    pts = np.vstack([scene.camera_region.center[None], pts])
    if scene.objects_of("abdominal_wall"):
        outside = ~caster.enclosed(pts)
        if outside[0] or outside.mean() > 0.5:
            raise UserError(f"the camera region of scene '{scene.name}' lies outside the abdominal wall")
    inside = caster.containing_object(pts)
    if inside[0] >= 0 or (inside >= 0).mean() > 0.5:
        k = int(np.bincount(inside[inside >= 0]).argmax())
        raise UserError(
            f"the camera region of scene '{scene.name}' lies inside organ '{scene.objects[k].name}'"
        )


# --- many views, both cores ----------------------------------------------------------------


def caster_setup(source: "SceneGeometry | str | os.PathLike") -> RayCaster:
    """A worker's ray caster (:class:`~sim2real.pool.WorkerPool` setup): from a
    :class:`SceneGeometry`, or from a scene folder that the worker loads itself."""
    if isinstance(source, SceneGeometry):
        return RayCaster(source)

    return RayCaster(Scene.load(source))


def render_camera(caster: RayCaster, camera: Camera) -> GBuffer:
    """The G-buffer of one camera (a :class:`~sim2real.pool.WorkerPool` job)."""
    return caster.render(camera)


def _render_to_file(caster: RayCaster, job: tuple[Camera, str, bool]) -> str:
    camera, path, preview = job
    g = caster.render(camera)
    g.save(path, durable=False)  # in the worker: only the path goes back; fsync'd together at the end
    if preview:

        save_preview(g, Path(path).with_suffix(".png"))
    return path


def render_views(
    scene: "Scene | str | os.PathLike",
    cameras: Iterable[Camera],
    paths: Sequence[str | os.PathLike],
    workers: int | None = None,
    preview: bool = False,
    progress: bool = True,
    caster: RayCaster | None = None,
) -> list[str]:
    """Render ``cameras`` of ``scene`` (a :class:`Scene` or its folder) to ``paths`` (.npz), in a
    process pool of ``workers`` (default: the usable cores, at most one per view) that starts
    before the first camera is drawn. ``cameras`` may be lazy (e.g.
    :func:`sim2real.scene.trajectory.iter_poses`): it is drawn as fast as the workers render.
    ``caster`` (of the same scene) is reused in-process and gives the workers its geometry."""
    if caster is None:
        if not isinstance(scene, (str, os.PathLike)):
            geometry = SceneGeometry.of(scene)
        else:

            geometry = SceneGeometry.of(Scene.load(scene))
    else:
        geometry = caster.geometry
    paths = [str(p) for p in paths]
    workers = workers or worker_count(jobs=len(paths))
    done: list[str] = []
    with tqdm(total=len(paths), desc="render", unit="view", disable=not progress) as bar, \
            WorkerPool(workers, caster_setup, (geometry,), state=caster) as pool:
        jobs = ((cam, path, preview) for cam, path in zip(cameras, paths))
        for path in pool.imap(_render_to_file, jobs):
            done.append(path)
            bar.update()
    fsync_files(done)  # durable before the caller writes the folder's manifest
    return done
