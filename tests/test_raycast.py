import numpy as np
import pytest

from sim2real.render.gbuffer import GBuffer
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at, pixel_centres, pixel_rays, project


@pytest.fixture(scope="module")
def view(analytic_scene):
    cam = Camera(intrinsics_from_fov(96, 64, 80.0), look_at([0, 0, 100], [0, 0, 0], [0, 1, 0]), 64, 96)
    return cam, RayCaster(analytic_scene).render(cam)


def _closed_form(cam):
    """Independent ray-plane / ray-sphere intersection for every pixel."""
    o, d = pixel_rays(cam)
    c, r = np.array([0.0, 0.0, 30.0]), 20.0
    oc = o - c
    b = d @ oc
    disc = b**2 - (oc @ oc - r * r)
    t_sphere = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    t_plane = -o[2] / d[..., 2]
    on_sphere = t_sphere < t_plane
    t = np.where(on_sphere, t_sphere, t_plane)
    p = o + d * t[..., None]
    n = np.where(on_sphere[..., None], (p - c) / r, np.array([0.0, 0.0, 1.0]))
    return on_sphere, p, n


def test_analytic_scene_matches_closed_form(view):
    cam, g = view
    on_sphere, p, n = _closed_form(cam)
    assert (g.object_id == np.where(on_sphere, 1, 0)).mean() > 0.995  # silhouette pixels may differ
    agree = g.object_id == np.where(on_sphere, 1, 0)
    # icosphere (subdivision 6) deviates from the true sphere by < 0.005 mm
    np.testing.assert_allclose(g.points[agree], p[agree], atol=0.02)
    np.testing.assert_allclose(g.depth[agree], 100.0 - p[agree][:, 2], atol=0.02)
    plane = agree & ~on_sphere
    np.testing.assert_allclose(g.depth[plane], 100.0, atol=1e-3)  # z-depth of a fronto-parallel plane
    cos = np.einsum("ij,ij->i", g.normal[agree], n[agree])
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.5
    np.testing.assert_allclose(np.linalg.norm(g.normal[agree], axis=1), 1.0, atol=1e-5)
    # distance is Euclidean, depth is z: they differ off the optical axis.
    np.testing.assert_allclose(g.distance[agree], np.linalg.norm(p[agree] - [0, 0, 100], axis=1), atol=0.02)


def test_points_project_onto_pixel_centres(view):
    cam, g = view
    uv, z = project(g.points.astype(np.float64), g.K, g.world_to_camera)
    err = np.abs(uv - pixel_centres(cam.height, cam.width))[g.mask]
    assert err.max() < 1e-3
    np.testing.assert_allclose(z[g.mask], g.depth[g.mask], atol=1e-3)


def test_missed_rays_are_background_not_a_crash(analytic_scene):
    # Looking away from everything: every ray misses.
    cam = Camera(intrinsics_from_fov(32, 16, 60), look_at([0, 0, 100], [0, 0, 200], [0, 1, 0]), 16, 32)
    g = RayCaster(analytic_scene).render(cam)
    assert (g.object_id == -1).all() and (g.depth == 0).all() and (g.points == 0).all()


def test_normals_face_the_camera(procedural_scene, procedural_caster):
    from sim2real.scene.trajectory import sample_poses

    cam = sample_poses(procedural_caster, 1, 48, 64, 75, seed=5)[0]
    g = procedural_caster.render(cam)
    to_cam = cam.position - g.points
    assert (np.einsum("hwc,hwc->hw", g.normal, to_cam)[g.mask] > 0).all()


def test_gbuffer_save_load_round_trip(tmp_path, view):
    _, g = view
    g.save(tmp_path / "v.npz")
    back = GBuffer.load(tmp_path / "v.npz")
    for k in ("K", "world_to_camera", "depth", "distance", "normal", "object_id", "points"):
        np.testing.assert_array_equal(getattr(back, k), getattr(g, k))
        # bit for bit, dtype and shape kept (float32 points / depth are not rounded or widened)
        a, b = getattr(back, k), getattr(g, k)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), k
    assert back.points.dtype == np.float32 and back.depth.dtype == np.float32
    assert back.classes == ("liver", "fat")
    # class_index maps object ids to the fixed class order (fat is class 1, liver 0)
    assert set(np.unique(back.class_index())) <= {0, 1}
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_view_files_are_stored_uncompressed_and_old_compressed_files_still_load(tmp_path, view):
    import zipfile

    _, g = view
    g.save(tmp_path / "new.npz")
    with zipfile.ZipFile(tmp_path / "new.npz") as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
    # The writer of earlier versions: numpy's savez_compressed of the same keys.
    np.savez_compressed(tmp_path / "old.npz", K=g.K, world_to_camera=g.world_to_camera, depth=g.depth,
                        distance=g.distance, normal=g.normal, object_id=g.object_id, points=g.points,
                        classes=np.array(g.classes, dtype=str))
    old = GBuffer.load(tmp_path / "old.npz")
    assert old.points.tobytes() == g.points.tobytes() and old.depth.tobytes() == g.depth.tobytes()
    assert old.classes == g.classes


def test_caster_from_geometry_renders_like_the_scene(procedural_scene, procedural_caster):
    from sim2real.render.raycast import SceneGeometry
    from sim2real.scene.trajectory import sample_poses

    geometry = SceneGeometry.of(procedural_scene)
    assert "trimesh" not in {type(a).__module__.split(".")[0] for a in geometry.vertices}
    bare = RayCaster(geometry)
    assert bare.scene is None and bare.classes == procedural_scene.classes
    for cam in sample_poses(procedural_caster, 2, 24, 40, 75, seed=3):
        a, b = bare.render(cam), procedural_caster.render(cam)
        for k in ("depth", "normal", "object_id", "points"):
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    pts = procedural_scene.camera_region.sample(np.random.default_rng(0), 32)
    np.testing.assert_array_equal(bare.free_space(pts), procedural_caster.free_space(pts))


def test_inside_tests(analytic_scene):
    caster = RayCaster(analytic_scene)
    pts = np.array([[0, 0, 30.0], [0, 0, 60.0], [0, 0, 45.0]])
    np.testing.assert_array_equal(caster.containing_object(pts), [1, -1, 1])
