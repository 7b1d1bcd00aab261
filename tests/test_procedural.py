import numpy as np
from conftest import private_outputs

from sim2real.scene.procedural import generate_scene
from sim2real.scene.scene import CLASSES, Scene
from sim2real.scene.trajectory import Trajectory, make_trajectory, sample_poses


def test_deterministic_per_seed_and_different_across_seeds():
    a, b, c = generate_scene(5), generate_scene(5), generate_scene(6)
    for oa, ob in zip(a.objects, b.objects):
        np.testing.assert_array_equal(oa.mesh.vertices, ob.mesh.vertices)
    assert not np.allclose(a.objects[0].mesh.vertices, c.objects[0].mesh.vertices)


def test_every_class_present_closed_and_plausible(procedural_scene):
    assert sorted(procedural_scene.classes) == sorted(CLASSES)
    for obj in procedural_scene.objects:
        assert obj.mesh.is_watertight and obj.mesh.is_winding_consistent, obj.name
        assert obj.mesh.volume > 0, obj.name  # outward orientation
    liver = procedural_scene.objects[procedural_scene.objects_of("liver")[0]].mesh
    assert 150.0 <= liver.extents.max() <= 250.0
    assert liver.extents.min() > 25.0


def test_scene_save_load_round_trip(tmp_path, procedural_scene):
    procedural_scene.save(tmp_path / "s")
    assert private_outputs(tmp_path / "s", tmp_path) == []
    back = Scene.load(tmp_path / "s")
    assert back.classes == procedural_scene.classes
    for o1, o2 in zip(back.objects, procedural_scene.objects):
        np.testing.assert_allclose(o1.mesh.vertices, o2.mesh.vertices, atol=1e-4)


def _inside_by_winding(mesh, pts):
    """Independent inside test: generalised winding number (solid angles of all triangles)."""
    tri = mesh.triangles[None] - pts[:, None, None, :]  # (P, F, 3, 3)
    a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", a, c) * lb + np.einsum("pfi,pfi->pf", b, c) * la
    return np.abs((2 * np.arctan2(num, den)).sum(axis=1) / (4 * np.pi)) > 0.5


def test_random_poses_outside_organs_and_liver_in_view(procedural_scene, procedural_caster):
    cams = sample_poses(procedural_caster, 12, 48, 96, 75, seed=1)
    eyes = np.array([c.position for c in cams])
    liver_mesh = procedural_scene.objects[procedural_scene.objects_of("liver")[0]].mesh
    assert _inside_by_winding(liver_mesh, liver_mesh.centroid[None]).all()  # the check can fail
    for obj in procedural_scene.objects:
        if obj.cls != "abdominal_wall":
            assert not _inside_by_winding(obj.mesh, eyes).any(), obj.name
    wall = procedural_scene.objects[procedural_scene.objects_of("abdominal_wall")[0]].mesh
    assert not _inside_by_winding(wall, eyes).any()  # in the cavity, not in the wall's tissue
    liver = procedural_scene.objects_of("liver")[0]
    shares = [(procedural_caster.render(c).object_id == liver).mean() for c in cams]
    assert np.mean(np.array(shares) > 0.15) >= 0.75
    # the head direction points up in the image: camera -y axis has a positive world-y part
    assert all(-c.world_to_camera[1, 1] > 0 for c in cams)


def test_trajectory_is_smooth_and_round_trips(tmp_path, procedural_caster):
    traj = make_trajectory(procedural_caster, frames=100, height=32, width=64, seed=4)
    eyes = np.array([c.position for c in traj.cameras])
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert len(traj.cameras) == 100 and steps.max() < 5 * np.median(steps) + 1e-6
    depth_range = [procedural_caster.render(traj.cameras[i]).depth.max() for i in (0, 50, 99)]
    assert max(depth_range) - min(depth_range) > 1.0  # varying distance
    traj.save(tmp_path / "t.txt")
    back = Trajectory.load(tmp_path / "t.txt")
    assert back.fps == 5.0 and len(back.cameras) == 100
    for c1, c2 in zip(back.cameras, traj.cameras):
        np.testing.assert_allclose(c1.world_to_camera, c2.world_to_camera, atol=1e-6)
        np.testing.assert_allclose(c1.K, c2.K)


def test_lazy_poses_are_the_sampled_poses_and_check_their_arguments_at_once(procedural_caster):
    import pytest

    from sim2real.errors import UserError
    from sim2real.scene.trajectory import iter_poses

    eager = sample_poses(procedural_caster, 5, 24, 40, 75, seed=8)
    lazy = iter_poses(procedural_caster, 5, 24, 40, 75, seed=8)
    assert not isinstance(lazy, list)
    lazy = list(lazy)
    assert len(lazy) == 5
    for a, b in zip(eager, lazy):
        np.testing.assert_array_equal(a.world_to_camera, b.world_to_camera)
    assert len({c.position.tobytes() for c in lazy}) == 5
    with pytest.raises(UserError, match="at least 1"):
        iter_poses(procedural_caster, 0, 24, 40, 75, seed=8)  # raised by the call, not by a first next()
    with pytest.raises(UserError, match="field of view"):
        iter_poses(procedural_caster, 2, 24, 40, 200, seed=8)
