import numpy as np
import pytest
from conftest import plane_mesh, segment_hits_box

from sim2real.render.raycast import RayCaster
from sim2real.render.warp import correspondences, flow, warp_image
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at, pixel_centres
from sim2real.scene.scene import CameraRegion, Scene, SceneObject


def test_occluded_points_are_masked(hiding_scene):
    caster = RayCaster(hiding_scene)
    K = intrinsics_from_fov(128, 96, 70)
    ci = Camera(K, look_at([0, 0, 100], [0, 0, 0], [0, 1, 0]), 96, 128)
    cj = Camera(K, look_at([70, 0, 90], [0, 0, 0], [0, 1, 0]), 96, 128)
    gi, gj = caster.render(ci), caster.render(cj)
    uv, visible = correspondences(gi, gj)
    floor = gi.object_id == 0
    hidden = floor & segment_hits_box(gi.points.astype(np.float64), cj.position)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < 128) & (uv[..., 1] >= 0) & (uv[..., 1] < 96)
    assert hidden.sum() > 100  # the scene really hides part of the floor from view j
    # Every floor point that the box hides from j is masked (the authors' sign error kept them).
    assert not (visible & hidden).any()
    # Floor points with a free line of sight to j, away from the box's silhouette, are kept.
    free = floor & inside & ~hidden & ~_near(hidden, 2)
    assert visible[free].mean() > 0.99


def test_surface_seen_at_a_grazing_angle_is_not_self_occluded():
    """A plane with nothing on it, seen by j at ~80 degrees from its normal: every point of i that
    lands inside j is visible. j's depth buffer is read at the nearest pixel, and across a pixel
    the depth of such a surface changes by ~(z / f) tan(80 deg), several times a 1 mm tolerance."""
    caster = RayCaster(Scene("plane", [SceneObject("floor", "liver", plane_mesh(half=5000.0))],
                             CameraRegion([0, 0, 100], [5, 5, 5])))
    K = intrinsics_from_fov(256, 128, 75)
    ci = Camera(K, look_at([0, 0, 150], [0, 0, 0], [0, 1, 0]), 128, 256)
    cj = Camera(K, look_at([-300, 0, 60], [0, 0, 0], [0, 0, 1]), 128, 256)  # 78.7 deg at the target
    gi, gj = caster.render(ci), caster.render(cj)
    uv, visible = correspondences(gi, gj)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < 256) & (uv[..., 1] >= 0) & (uv[..., 1] < 128) & gi.mask
    assert inside.sum() > 5000
    assert visible[inside].all()


def _near(mask, r):
    from scipy.ndimage import binary_dilation

    return binary_dilation(mask, iterations=r)


@pytest.fixture(scope="module")
def view_pair(procedural_caster):
    from sim2real.scene.trajectory import make_trajectory

    traj = make_trajectory(procedural_caster, frames=30, height=96, width=160, seed=2)
    return procedural_caster.render(traj.cameras[10]), procedural_caster.render(traj.cameras[13])


def test_flow_forward_backward_returns_to_start(view_pair):
    gi, gj = view_pair
    f_ij, vis_ij = flow(gi, gj)
    f_ji, vis_ji = flow(gj, gi)
    assert vis_ij.mean() > 0.3
    p = pixel_centres(gi.height, gi.width)
    q = p + f_ij
    back = warp_image(f_ji, q, vis_ij)  # f_ji sampled at the positions in j
    # Only where all four pixels around q are visible back in i (no interpolation across edges).
    support = warp_image(vis_ji.astype(np.float32), q, vis_ij) > 0.999
    ok = vis_ij & support
    err = np.linalg.norm(q + back - p, axis=-1)[ok]
    assert ok.sum() > 1000
    assert np.median(err) < 0.02 and np.percentile(err, 95) < 0.2


def test_warp_reproduces_a_view_independent_image(view_pair):
    gi, gj = view_pair

    def solid(g):  # colour is a smooth function of the 3D point only
        return (np.sin(g.points / 7.0) * 0.5 + 0.5).astype(np.float32)

    uv, vis = correspondences(gi, gj)
    warped = warp_image(solid(gj), uv, vis)
    err = np.abs(warped - solid(gi)).max(axis=-1)[vis & ~_near(~vis, 1)]
    assert np.median(err) < 0.01
    assert (warped[~vis] == 0).all()
