"""Shared fixtures: tiny scenes built in the test session (nothing is downloaded)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sim2real.scene.scene import CameraRegion, Scene, SceneObject


def plane_mesh(z: float = 0.0, half: float = 500.0) -> trimesh.Trimesh:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False)


BOX_LO, BOX_HI = np.array([-6.0, -6.0, 20.0]), np.array([6.0, 6.0, 30.0])


@pytest.fixture(scope="module")
def hiding_scene():
    """A plane at z = 0 (liver) and a box between BOX_LO and BOX_HI above it (gallbladder)."""
    box = trimesh.creation.box(bounds=np.stack([BOX_LO, BOX_HI]))
    return Scene("hiding", [SceneObject("floor", "liver", plane_mesh()), SceneObject("box", "gallbladder", box)],
                 CameraRegion([0, 0, 100], [5, 5, 5]))


def segment_hits_box(p, q, lo=BOX_LO, hi=BOX_HI):
    """Slab test: does the open segment p -> q pass through the box [lo, hi]? (independent of Embree)"""
    d = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - p) / d, (hi - p) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    return (tmax >= tmin) & (tmax > 1e-6) & (tmin < 1 - 1e-6)


def private_outputs(root, scratch) -> list:
    """The files and folders under ``root`` (``root`` too) whose permissions differ from what a
    plain ``mkdir`` and ``open`` give in ``scratch`` under the same umask (0755 and 0644 under
    022): an output made private by a temporary name's permissions shows up here."""
    import os

    (scratch / "plain").mkdir()
    (scratch / "plain" / "f").write_text("")
    want = {True: os.stat(scratch / "plain").st_mode, False: os.stat(scratch / "plain" / "f").st_mode}
    return [p for p in [root, *root.rglob("*")] if not p.is_symlink() and os.lstat(p).st_mode != want[p.is_dir()]]


def sphere_mesh(centre, radius: float, subdivisions: int = 6) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_translation(centre)
    return m


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    """Trained segmenters are cached under $SIM2REAL_CACHE: a fresh one per test session."""
    import os

    old = os.environ.get("SIM2REAL_CACHE")
    os.environ["SIM2REAL_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if old is None:
        os.environ.pop("SIM2REAL_CACHE", None)
    else:
        os.environ["SIM2REAL_CACHE"] = old


@pytest.fixture(scope="module")
def train_inputs(tmp_path_factory):
    """(scene folder, real-image folder) for training commands: procedural scene 11, 4 images."""
    from train_data import real_dir, scene_dir

    base = tmp_path_factory.getbasetemp()
    return scene_dir(base, 11), real_dir(base)


@pytest.fixture(scope="module")
def video_train_inputs(tmp_path_factory):
    """(scene folder, real folder with one 6-frame sequence) for the video methods (triplets)."""
    from train_data import real_video_dir, scene_dir

    base = tmp_path_factory.getbasetemp()
    return scene_dir(base, 11), real_video_dir(base)


@pytest.fixture(scope="module")
def one_torch_thread():
    """torch on one thread for a module: 2 OpenMP threads on 2 shared, busy cores spin against
    each other (10x slower on the dev machine)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def analytic_scene() -> Scene:
    """A plane z = 0 (class liver) and a sphere of radius 20 mm centred at (0, 0, 30) (fat)."""
    return Scene(
        "analytic",
        [SceneObject("plane", "liver", plane_mesh()), SceneObject("ball", "fat", sphere_mesh([0, 0, 30], 20.0))],
        CameraRegion([0, 0, 100], [10, 10, 10]),
    )


@pytest.fixture(scope="session")
def procedural_scene():
    from sim2real.scene.procedural import generate_scene

    return generate_scene(11)


@pytest.fixture(scope="session")
def procedural_caster(procedural_scene):
    from sim2real.render.raycast import RayCaster

    return RayCaster(procedural_scene)
