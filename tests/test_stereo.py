"""The stereo pair's geometry: the right eye of a camera, the left view's disparity and its mask,
checked on a plane with a box on it against the pinhole formulas worked out here."""

import numpy as np
from conftest import BOX_HI, BOX_LO, segment_hits_box

from sim2real.inference.stereo import disparity, right_camera
from sim2real.render.raycast import RayCaster
from sim2real.render.warp import correspondences
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at

H, W, B = 96, 128, 5.0


def test_right_eye_is_the_left_camera_moved_along_its_x_axis():
    left = Camera(intrinsics_from_fov(W, H, 70), look_at([30, -20, 90], [0, 0, 0], [0, 1, 0]), H, W)
    right = right_camera(left, B)
    c2w_l, c2w_r = left.camera_to_world, right.camera_to_world
    assert np.allclose(c2w_r[:3, :3], c2w_l[:3, :3], atol=1e-12) and np.array_equal(right.K, left.K)
    assert np.allclose(c2w_r[:3, 3], c2w_l[:3, 3] + B * c2w_l[:3, 0], atol=1e-9)  # B mm along the left's x axis
    assert (right.height, right.width) == (H, W)


def test_disparity_moves_each_point_along_its_row(hiding_scene):
    caster = RayCaster(hiding_scene)
    left = Camera(intrinsics_from_fov(W, H, 70), look_at([0, -40, 90], [0, 0, 0], [0, 0, 1]), H, W)
    gl, gr = caster.render(left), caster.render(right_camera(left, B))
    d = disparity(gl, B)
    fx = left.K[0, 0]
    assert d.dtype == np.float32 and (d[~gl.mask] == 0).all()
    assert np.allclose(d[gl.mask], fx * B / gl.depth[gl.mask], rtol=1e-6)
    uv, seen = correspondences(gl, gr)
    v, u = np.mgrid[0:H, 0:W] + 0.5
    assert np.abs(uv[..., 0][seen] - (u - d)[seen]).max() < 1e-3  # the same row, d pixels to the left
    assert np.abs(uv[..., 1][seen] - v[seen]).max() < 1e-3
    assert 3 < np.median(d[gl.mask]) < 12  # fx ~ 91 px, B 5 mm, depths ~ 40-160 mm
    # the box hides some floor from the right eye, and those pixels are masked
    floor = gl.object_id == 0
    hidden = floor & segment_hits_box(gl.points.astype(np.float64), right_camera(left, B).position, BOX_LO + 0.5, BOX_HI - 0.5)
    assert hidden.sum() > 10 and not (seen & hidden).any()
