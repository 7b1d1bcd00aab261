"""View pools: a fixed set of ``data.view_pool`` random training poses per scene whose G-buffers
are ray-cast once into a memory-mapped file and read, epoch after epoch, by every loader worker,
every DDP rank and every later run of the same scene (``--resume`` included).

* **Poses.** Pose ``k`` of a scene's pool is a pure function of (training seed, scene name, k)
  (:func:`pool_camera`: :func:`sim2real.scene.trajectory.sample_poses` seeded from those three),
  so the pool of 16 views begins with the pool of 8, and ray-casting pose ``k`` again gives the
  view the file holds (up to its storage dtypes).
* **Storage.** One structured ``.npy`` per pool, ``gbuffers.npy`` of shape (N, H, W), opened
  with ``mmap_mode='r'`` (the workers share the page cache, nothing is decoded into each
  worker's memory), beside ``cameras.npy`` (N, 4, 4) and ``pool.json``. The fields are the
  transfer dtypes of :func:`sim2real.data.tensors.compact`: object ids int16, normals fp16,
  surface points, depth and distance fp16 when every coordinate of the scene (its objects'
  bounding boxes and camera region) and every distance within it stay below
  :data:`~sim2real.data.tensors.FP16_POINTS_MAX_MM` (rounding at most 0.25 mm, inside the 1 mm
  occlusion rule), else fp32. 18 bytes a pixel (fp16): 2.25 MiB a 256x512 view, against 4.25 MB
  for a views folder's ``.npz``. A view read back is widened to float32 (:meth:`ViewPool.view`);
  what a sample carries to the device is then bit for bit what a freshly ray-cast view of the
  same pose carries (compact rounds it the same way); only what the worker computes from the
  geometry (correspondences, and on a CPU run a_ref) sees the rounding.
* **Where.** ``$SIM2REAL_CACHE/views/KEY/`` (default ``~/.cache/sim2real``), KEY = SHA-256 of
  the scene folder's bytes (``scene.json`` and its meshes), the view size, field of view, pool
  size, seed, background limit and the versions of sim2real and embreex: the runs of several
  methods on one scene share one pool, and an edited scene gets a new one.
* **When.** Up front, before the first step, with every core of the process's share
  (:func:`sim2real.threads.worker_count`) and a progress bar, not lazily in the first epoch: the
  file is complete when it appears (written under a temporary folder name, flushed, then renamed),
  so readers never meet a half-written view and need no per-view flags; the cost is paid once at
  full speed instead of a first epoch at the fresh-view rate; and the step clock (data-wait
  figures) starts with the data ready. A file lock (``KEY.lock``) lets one process build while
  the others (DDP ranks, concurrent runs) wait and then read.
* **Damage.** A pool folder whose files do not match ``pool.json`` (truncated, resized, missing)
  is reported in one line and built again.

Video methods train on short linear paths (data/triplets.py), which a pool of single poses cannot
supply: they ray-cast their paths as before and build no pool.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
from tqdm import tqdm

try:
    import fcntl
except ImportError:  # Windows: not a target; pools are then built without a lock
    fcntl = None

from sim2real import __version__
from sim2real.config import DataConfig
from sim2real.errors import UserError, reason
from sim2real.fileio import atomic_write_json, cache_root, check_free_space, fsync_files, read_json, temp_dir_beside
from sim2real.pool import WorkerPool
from sim2real.render.gbuffer import GBuffer
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import view_intrinsics
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import MAX_BACKGROUND, sample_poses
from sim2real.threads import worker_count

POOL_FORMAT = "sim2real-view-pool/1"
MANIFEST = "pool.json"
GBUFFERS = "gbuffers.npy"
CAMERAS = "cameras.npy"
FP16_GEOMETRY_MAX_MM = 1024.0
"""Geometry is stored as fp16 while every coordinate and distance of the scene stays below this
(the bound of :data:`sim2real.data.tensors.FP16_POINTS_MAX_MM`: rounding at most 0.25 mm)."""


def pool_dtype(fp16_geometry: bool) -> np.dtype:
    """One pixel of a pooled view: 18 bytes with fp16 geometry, 30 with fp32."""
    g = "<f2" if fp16_geometry else "<f4"
    return np.dtype([("depth", g), ("distance", g), ("normal", "<f2", (3,)), ("points", g, (3,)),
                     ("object_id", "<i2")])


def bytes_per_view(height: int, width: int, fp16_geometry: bool = True) -> int:
    """Disk bytes of one pooled view (G-buffer and its 4x4 camera)."""
    return height * width * pool_dtype(fp16_geometry).itemsize + 4 * 4 * 8


def fp16_fits(scene: Scene) -> bool:
    """Whether every surface point, depth and distance of ``scene``'s views stays below
    :data:`FP16_GEOMETRY_MAX_MM`: the box around its objects and its camera region must lie
    within that of the origin on every axis and have a shorter diagonal."""
    b = scene.bounds()
    region = scene.camera_region
    lo = np.minimum(b[:, 0].min(axis=0), region.center - region.radii)
    hi = np.maximum(b[:, 1].max(axis=0), region.center + region.radii)
    return bool(max(np.abs(lo).max(), np.abs(hi).max()) < FP16_GEOMETRY_MAX_MM
                and np.linalg.norm(hi - lo) < FP16_GEOMETRY_MAX_MM)


def scene_digest(scene_dir: str | os.PathLike) -> str:
    """SHA-256 over a scene folder's ``scene.json`` and the mesh files it names, in its order."""
    scene_dir = Path(scene_dir)
    spec = read_json(scene_dir / "scene.json", "scene description")
    h = hashlib.sha256((scene_dir / "scene.json").read_bytes())
    for entry in spec.get("objects", []):
        h.update(hashlib.sha256((scene_dir / entry["mesh"]).read_bytes()).digest())
    return h.hexdigest()


def pose_seed(seed: int, scene_name: str, index: int) -> int:
    """The random seed of pose ``index`` of scene ``scene_name``'s pool under training seed ``seed``."""
    name = int.from_bytes(hashlib.sha256(scene_name.encode()).digest()[:8], "little")
    return int(np.random.SeedSequence([int(seed), name, int(index)]).generate_state(1, np.uint64)[0])


def pool_camera(caster: RayCaster, spec: dict, index: int):
    """Pose ``index`` of the pool of ``spec`` (:func:`pool_spec`): a random training pose
    (:func:`sample_poses`' rules) drawn from :func:`pose_seed` alone, with the spec's intrinsics
    (``intrinsics`` where it has them, else ``fov_x_deg``'s)."""
    h, w = spec["height"], spec["width"]
    return sample_poses(caster, 1, h, w, spec["fov_x_deg"], seed=pose_seed(spec["seed"], spec["scene"], index),
                        K=pool_intrinsics(spec))[0]


def pool_intrinsics(spec: dict) -> np.ndarray:
    """The K of every view of the pool of ``spec``."""
    return view_intrinsics(spec["width"], spec["height"], spec["fov_x_deg"], spec.get("intrinsics"))


def pool_spec(scene_dir: str | os.PathLike, scene_name: str, cfg: DataConfig, seed: int) -> dict:
    """Everything a pool's content depends on (its cache key is the hash of this)."""
    try:
        embree = metadata.version("embreex")
    except metadata.PackageNotFoundError:  # pragma: no cover - embreex is a dependency
        embree = "unknown"
    spec = {"format": POOL_FORMAT, "scene": scene_name, "scene_sha256": scene_digest(scene_dir),
            "height": int(cfg.height), "width": int(cfg.width), "fov_x_deg": float(cfg.fov_x_deg),
            "views": int(cfg.view_pool), "seed": int(seed), "max_background": MAX_BACKGROUND,
            "sim2real": __version__, "embreex": embree}
    if cfg.intrinsics is not None:  # only then, so the pools cached without it keep their keys
        spec["intrinsics"] = [float(v) for v in cfg.intrinsics]
    return spec


def pool_folder(spec: dict) -> Path:
    key = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:32]
    return cache_root() / "views" / key


# --- reading --------------------------------------------------------------------------------


class ViewPool:
    """The views of one scene's pool. ``view(k)`` reads view ``k`` from the memory-mapped file
    (``folder`` given) or, with ``folder=None``, ray-casts pose ``k`` again (the same samples
    without a cache; the tests compare the two)."""

    def __init__(self, spec: dict, scene_dir: Path, classes: tuple[str, ...], class_table, folder: Path | None):
        self.spec, self.scene_dir, self.classes, self.class_table = spec, Path(scene_dir), classes, class_table
        self.folder = None if folder is None else Path(folder)
        self.K = pool_intrinsics(spec)
        self._arrays = None
        self._caster = None
        self._pid = os.getpid()

    def __len__(self) -> int:
        return int(self.spec["views"])

    def __getstate__(self):  # loader workers map the file themselves (a pickled memmap is a copy)
        state = self.__dict__.copy()
        state["_arrays"], state["_caster"] = None, None
        return state

    def _open(self):
        if self._arrays is None:
            self._arrays = (np.load(self.folder / GBUFFERS, mmap_mode="r"), np.load(self.folder / CAMERAS))
        return self._arrays

    def view(self, k: int) -> GBuffer:
        if self.folder is None:
            return self._recast(k)
        gbuffers, cameras = self._open()
        rec = gbuffers[int(k)]
        f32 = np.float32
        return GBuffer(self.K.copy(), cameras[int(k)].copy(), rec["depth"].astype(f32), rec["distance"].astype(f32),
                       rec["normal"].astype(f32), np.array(rec["object_id"]), rec["points"].astype(f32),
                       self.classes, self.class_table)

    def _recast(self, k: int) -> GBuffer:
        if self._caster is None or self._pid != os.getpid():  # never a forked parent's Embree objects
            self._caster, self._pid = RayCaster(Scene.load(self.scene_dir)), os.getpid()
        cam = pool_camera(self._caster, self.spec, k)
        return self._caster.render(cam)


def check_pool(folder: Path, spec: dict) -> str | None:
    """Why the pool in ``folder`` cannot be used for ``spec`` (one phrase), or None if it can."""
    try:
        manifest = read_json(folder / MANIFEST, "view pool manifest")
    except UserError as e:
        return str(e)
    if manifest.get("spec") != spec:
        return "its pool.json describes another pool"
    fp16 = bool(manifest.get("fp16_geometry"))
    n, h, w = spec["views"], spec["height"], spec["width"]
    try:
        g = np.load(folder / GBUFFERS, mmap_mode="r")
        c = np.load(folder / CAMERAS, mmap_mode="r")
    except (OSError, ValueError) as e:
        return f"{GBUFFERS if 'gbuffers' in str(e) else 'a file'} cannot be mapped ({e})"
    if g.shape != (n, h, w) or g.dtype != pool_dtype(fp16):
        return f"{GBUFFERS} holds {g.dtype} {g.shape}, not {(n, h, w)}"
    if c.shape != (n, 4, 4):
        return f"{CAMERAS} holds {c.shape}, not {(n, 4, 4)}"
    expected = g.offset + g.nbytes
    size = (folder / GBUFFERS).stat().st_size
    if size != expected:
        return f"{GBUFFERS} has {size} bytes, not {expected}"
    return None


# --- building -------------------------------------------------------------------------------


class _Builder:
    """A build worker's state: its ray caster and the pool file being written."""

    def __init__(self, caster: RayCaster, path: str, spec: dict):
        self.caster, self.path, self.spec, self.gbuffers = caster, path, spec, None


def _builder_setup(scene_dir: str, path: str, spec: dict) -> _Builder:
    # the whole scene, not only its geometry: drawing a pose needs its camera region and anatomy
    return _Builder(RayCaster(Scene.load(scene_dir)), path, spec)


def _build_view(state: _Builder, k: int) -> tuple[int, np.ndarray, int]:
    """Ray-cast pose ``k`` into slot ``k`` of the file; returns (k, world_to_camera, views
    skipped for background)."""
    if state.gbuffers is None:
        state.gbuffers = np.load(state.path, mmap_mode="r+")
    before = state.caster.skipped_background
    cam = pool_camera(state.caster, state.spec, k)
    g = state.caster.render(cam)
    slot = state.gbuffers[k]
    for name in ("depth", "distance", "normal", "points", "object_id"):
        slot[name] = getattr(g, name)
    return k, np.asarray(g.world_to_camera, np.float64), state.caster.skipped_background - before


def _build(folder: Path, spec: dict, scene_dir: Path, scene: Scene, progress: bool) -> None:
    n, h, w = spec["views"], spec["height"], spec["width"]
    fp16 = fp16_fits(scene)
    need = n * bytes_per_view(h, w, fp16)
    check_free_space(folder.parent, need, f"the view pool of scene '{spec['scene']}'",
                     "point SIM2REAL_CACHE elsewhere, lower data.view_pool, or set data.view_pool=0 "
                     "(fresh views, no disk)")
    tmp = temp_dir_beside(folder)
    try:
        path = tmp / GBUFFERS
        np.lib.format.open_memmap(path, mode="w+", dtype=pool_dtype(fp16), shape=(n, h, w)).flush()
        cameras = np.zeros((n, 4, 4), np.float64)
        workers = worker_count(jobs=n)
        # in this process, the scene already loaded; spawned workers load their own
        here = _Builder(RayCaster(scene), str(path), spec) if workers <= 1 else None
        skipped = 0
        with tqdm(total=n, desc=f"view pool '{spec['scene']}'", unit="view", disable=not progress) as bar, \
                WorkerPool(workers, _builder_setup, (str(scene_dir), str(path), spec), state=here) as pool:
            for k, w2c, skip in pool.imap(_build_view, range(n)):
                cameras[k] = w2c
                skipped += skip
                bar.update()
        np.save(tmp / CAMERAS, cameras)
        fsync_files([path, tmp / CAMERAS])
        atomic_write_json(tmp / MANIFEST, {"spec": spec, "fp16_geometry": fp16, "dtype": str(pool_dtype(fp16)),
                                           "bytes": need, "skipped_background": skipped})
        if folder.exists():  # a damaged pool, reported by the caller
            shutil.rmtree(folder)
        os.replace(tmp, folder)
        fsync_files([folder.parent])
    except OSError as e:
        raise UserError(f"cannot write the view pool of scene '{spec['scene']}' to {folder}: "
                        f"{reason(e)}; set data.view_pool=0 to train on fresh views") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    if skipped:
        print(f"scene '{spec['scene']}': {skipped} random views skipped while building its view pool "
              f"(more than {MAX_BACKGROUND:.0%} background: rays escape through open meshes)", file=sys.stderr)


class _Lock:
    """An exclusive ``flock`` on ``path`` (blocking): one process builds a pool, the others wait."""

    def __init__(self, path: Path):
        self.path, self.fd = path, None

    def __enter__(self):
        if fcntl is not None:
            self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(self.fd, fcntl.LOCK_EX)
            except OSError:  # a file system without locks: builders may race, each rename is atomic
                pass
        return self

    def __exit__(self, *exc):
        if self.fd is not None:
            os.close(self.fd)  # closing drops the lock
            self.fd = None


def open_pool(scene_dir: Path, scene: Scene | None, cfg: DataConfig, seed: int, progress: bool = True,
              cached: bool = True, name: str | None = None, classes=None, class_table=None) -> ViewPool:
    """The view pool of the scene in ``scene_dir`` for ``cfg`` (size, field of view,
    ``view_pool``) and ``seed``: read from the cache, or built there first (see the module
    docstring). ``cached=False`` gives the pool that ray-casts its poses at every read."""
    scene = scene if scene is not None else Scene.load(scene_dir)
    name = name or scene.name
    spec = pool_spec(scene_dir, name, cfg, seed)
    classes = tuple(classes if classes is not None else scene.classes)
    table = class_table if class_table is not None else scene.class_table
    if not cached:
        return ViewPool(spec, scene_dir, classes, table, None)
    folder = pool_folder(spec)
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create the view cache folder {folder.parent}: {reason(e)}; "
                        "point SIM2REAL_CACHE elsewhere or set data.view_pool=0") from None
    if folder.exists() and check_pool(folder, spec) is None:
        return ViewPool(spec, scene_dir, classes, table, folder)
    with _Lock(folder.parent / f"{folder.name}.lock"):
        if folder.exists():  # built by another process meanwhile, or damaged
            problem = check_pool(folder, spec)
            if problem is None:
                return ViewPool(spec, scene_dir, classes, table, folder)
            print(f"sim2real: view pool {folder} is damaged ({problem}); ray-casting it again", file=sys.stderr)
        _build(folder, spec, scene_dir, scene, progress)
    return ViewPool(spec, scene_dir, classes, table, folder)


def attach_view_pools(sources, cfg: DataConfig, seed: int, progress: bool = True, cached: bool = True) -> None:
    """Give every bare scene folder of ``sources`` its view pool (``cfg.view_pool`` > 0); views
    folders keep their own views."""
    if cfg.view_pool <= 0:
        return
    for src in sources:
        if src.view_files is None:
            src.pool = open_pool(src.scene_dir, None, cfg, seed, progress, cached, src.name, src.classes,
                                 src.class_table)
