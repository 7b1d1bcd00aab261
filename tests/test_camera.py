import numpy as np
import pytest

from sim2real.errors import UserError
from sim2real.scene.camera import (
    Camera,
    intrinsics_from_fov,
    invert_rigid,
    look_at,
    pixel_centres,
    pixel_rays,
    project,
    quaternion_to_rotation,
    rotation_to_quaternion,
    unproject_depth,
)


def _camera(h=24, w=40):
    K = intrinsics_from_fov(w, h, 70.0)
    return Camera(K, look_at([10.0, -20.0, 90.0], [0.0, 5.0, 0.0], [0, 1, 0]), h, w)


def test_intrinsics_closed_form():
    K = intrinsics_from_fov(512, 256, 90.0)
    # tan(45 deg) = 1: the image half-width 256 px equals the focal length.
    assert K[0, 0] == pytest.approx(256.0) and K[1, 1] == pytest.approx(256.0)
    assert (K[0, 2], K[1, 2]) == (256.0, 128.0)


def test_point_pixel_ray_point_round_trip():
    cam = _camera()
    origin, dirs = pixel_rays(cam)
    rng = np.random.default_rng(0)
    t = rng.uniform(10, 200, size=dirs.shape[:2])
    pts = origin + dirs * t[..., None]
    uv, z = project(pts, cam.K, cam.world_to_camera)
    np.testing.assert_allclose(uv, pixel_centres(cam.height, cam.width), atol=1e-9)
    back = unproject_depth(z, cam.K, cam.world_to_camera)
    np.testing.assert_allclose(back, pts, atol=1e-9)


def test_look_at_axes_follow_opencv():
    eye, target = np.array([0.0, 0.0, 100.0]), np.zeros(3)
    T = look_at(eye, target, [0, 1, 0])
    # z forward: the target is straight ahead at depth 100, at the principal point.
    pc = T[:3, :3] @ target + T[:3, 3]
    np.testing.assert_allclose(pc, [0, 0, 100], atol=1e-12)
    # up (+y world) appears upwards in the image, i.e. towards smaller v.
    K = intrinsics_from_fov(64, 32, 60)
    (u0, v0), _ = project(np.array([0.0, 0.0, 0.0]), K, T)
    (u1, v1), _ = project(np.array([0.0, 10.0, 0.0]), K, T)
    assert v1 < v0 and abs(u1 - u0) < 1e-9
    np.testing.assert_allclose(invert_rigid(T) @ T, np.eye(4), atol=1e-12)


def test_quaternion_round_trip():
    R = look_at([1, 2, 3], [4, -1, 0], [0, 1, 0])[:3, :3]
    q = rotation_to_quaternion(R)
    assert q[3] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(quaternion_to_rotation(q), R, atol=1e-12)


@pytest.mark.parametrize("h,w,fov", [(4, 64, 60), (64, 0, 60), (64, 64, 0.5), (64, 64, 179)])
def test_bad_sizes_and_fov_are_user_errors(h, w, fov):
    with pytest.raises(UserError):
        intrinsics_from_fov(w, h, fov)
