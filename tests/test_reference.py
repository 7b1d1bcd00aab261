import numpy as np

from sim2real.render.raycast import RayCaster
from sim2real.render.reference import ALBEDO, reference_rendering
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at


def _expected(albedo, cos, d):
    d = min(d, 100.0)
    return np.clip(np.array(albedo) * (0.9 * cos + 0.1) / (3.5e-5 * d * d + 4e-4 * d + 0.4), 0, 1)


def test_reference_rendering_closed_form(analytic_scene):
    # Far camera looking down at the plane (liver): centre pixel at 300 mm (clamped to 100).
    for height in (60.0, 300.0):
        cam = Camera(intrinsics_from_fov(33, 33, 60), look_at([200, 0, height], [200, 0, 0], [0, 1, 0]), 33, 33)
        g = RayCaster(analytic_scene).render(cam)
        a = reference_rendering(g)
        np.testing.assert_allclose(a[16, 16], _expected(ALBEDO["liver"], 1.0, height), atol=1e-5)
        # an off-centre pixel: cos of the angle to the normal and the Euclidean distance
        p = g.points[3, 29]
        v = cam.position - p
        dist = np.linalg.norm(v)
        np.testing.assert_allclose(a[3, 29], _expected(ALBEDO["liver"], v[2] / dist, dist), atol=1e-5)


def test_values_are_clipped_and_background_black(analytic_scene):
    cam = Camera(intrinsics_from_fov(32, 16, 60), look_at([0, 0, 100], [0, 0, 200], [0, 1, 0]), 16, 32)
    assert (reference_rendering(RayCaster(analytic_scene).render(cam)) == 0).all()
    cam = Camera(intrinsics_from_fov(32, 16, 60), look_at([0, 0, 55], [0, 0, 0], [0, 1, 0]), 16, 32)
    a = reference_rendering(RayCaster(analytic_scene).render(cam))  # 5 mm from the sphere
    assert a.max() <= 1.0 and a.min() >= 0.0
