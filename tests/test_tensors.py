"""view_tensors: G-buffers -> a_ref / object_id / points / normal tensors, checked value by value."""

import numpy as np
import torch

from sim2real.data.tensors import view_tensors
from sim2real.render.gbuffer import GBuffer
from sim2real.render.reference import ALBEDO, reference_rendering


def _gbuffer(ids) -> GBuffer:
    """A 1x3 view from a camera at the origin looking down +z (identity pose), classes (liver, fat).

    Pixel 0: object ``ids[0]`` at (0, 0, 100), facing the camera (cos 1).
    Pixel 1: object ``ids[1]`` at (0, 0, 200), normal 60 degrees off the view ray (cos 0.5).
    Pixel 2: background."""
    s = np.sqrt(3.0) / 2.0
    points = np.array([[[0.0, 0.0, 100.0], [0.0, 0.0, 200.0], [0.0, 0.0, 0.0]]], np.float32)
    normal = np.array([[[0.0, 0.0, -1.0], [s, 0.0, -0.5], [0.0, 0.0, 0.0]]], np.float32)
    return GBuffer(K=np.array([[2.0, 0, 1.5], [0, 2.0, 0.5], [0, 0, 1]]), world_to_camera=np.eye(4),
                   depth=np.array([[100.0, 200.0, 0.0]], np.float32), distance=np.array([[100.0, 200.0, 0.0]], np.float32),
                   normal=normal, object_id=np.array([[ids[0], ids[1], -1]], np.int16), points=points,
                   classes=("liver", "fat"))


def _a_ref(albedo_class: str, cos: float) -> np.ndarray:
    """The paper's a_ref at a clamped distance of 100 mm, L = 1 / (3.5e-5 * 100^2 + 4e-4 * 100 + 0.4)
    = 1 / 0.79, clipped to [0, 1]."""
    return np.clip(np.array(ALBEDO[albedo_class]) * (0.9 * cos + 0.1) / 0.79, 0.0, 1.0)


def test_values_dtypes_and_shapes():
    g0, g1 = _gbuffer((0, 1)), _gbuffer((1, 0))
    t = view_tensors([g0, g1], "j")
    assert sorted(t) == ["a_ref_j", "normal_j", "object_id_j", "points_j"]
    assert t["a_ref_j"].dtype == torch.float32 and t["a_ref_j"].shape == (2, 3, 1, 3)
    assert t["object_id_j"].dtype == torch.int64 and t["object_id_j"].shape == (2, 1, 3)
    assert t["points_j"].dtype == torch.float32 and t["points_j"].shape == (2, 1, 3, 3)
    assert t["normal_j"].dtype == torch.float32 and t["normal_j"].shape == (2, 1, 3, 3)

    assert t["object_id_j"].tolist() == [[[0, 1, -1]], [[1, 0, -1]]]
    assert t["points_j"][1, 0].tolist() == [[0.0, 0.0, 100.0], [0.0, 0.0, 200.0], [0.0, 0.0, 0.0]]
    assert t["normal_j"][0, 0, 0].tolist() == [0.0, 0.0, -1.0]
    assert t["normal_j"][0, 0, 1, 1:].tolist() == [0.0, -0.5]

    # a_ref in [-1, 1], channels first: view 0 has liver facing the camera, fat at cos 0.5;
    # view 1 swaps the objects; the background is 0 in [0, 1], so -1.
    a = t["a_ref_j"].numpy()
    np.testing.assert_allclose(a[0, :, 0, 0], 2 * _a_ref("liver", 1.0) - 1, atol=1e-5)  # (0.4304, 0.1266, 0.1266)
    np.testing.assert_allclose(a[0, :, 0, 1], 2 * _a_ref("fat", 0.5) - 1, atol=1e-5)  # (0.5918, 0.4038, 0.2506)
    np.testing.assert_allclose(a[1, :, 0, 0], 2 * _a_ref("fat", 1.0) - 1, atol=1e-5)  # (1, 0.7342, 0.4557): red clipped
    np.testing.assert_allclose(a[1, :, 0, 1], 2 * _a_ref("liver", 0.5) - 1, atol=1e-5)
    assert a[1, 0, 0, 0] == 1.0  # 0.85 / 0.79 > 1: clipped
    assert (a[:, :, 0, 2] == -1.0).all()


def test_a_ref_is_the_reference_rendering_in_minus_one_to_one():
    g = _gbuffer((0, 1))
    a = view_tensors([g], "i")["a_ref_i"][0]
    assert torch.equal(a, torch.from_numpy(reference_rendering(g).transpose(2, 0, 1) * 2.0 - 1.0))
