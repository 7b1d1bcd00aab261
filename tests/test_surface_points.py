"""The surface-point sampler behind the COLMAP model's points and the point tracks: its budget,
its per-frame grids and how it thins them, counted by hand."""

import numpy as np

from sim2real.inference.surface_points import PointSampler


def test_sampler_thins_every_frame_alike_under_its_budget():
    mask = np.ones((16, 16), bool)
    pts = np.zeros((16, 16, 3))
    s = PointSampler(budget=20, step=4)  # 16 grid points per frame
    s.add(0, mask, points=pts)
    assert len(s.frame(0)[0]) == 16 and s.thin == 1
    s.add(1, mask, points=pts)  # 32 > 20: every frame keeps every other of its grid points
    assert s.thin == 2 and [len(s.frame(i)[0]) for i in (0, 1)] == [8, 8]
    s.add(2, mask, points=pts)  # 8 + 8 + 8 = 24 > 20: every fourth
    assert s.thin == 4 and [len(s.frame(i)[0]) for i in (0, 1, 2)] == [4, 4, 4]
    rows, cols, _ = s.frame(1)
    assert set(rows % 4) == {3} and set(cols % 4) == {1}  # frame 1's grid is offset by (3, 5 mod 4)
    holes = np.ones((16, 16), bool)
    holes[:8] = False  # no surface in the top half: only surface pixels are taken
    s.add(3, holes, points=pts)
    assert len(s.frame(3)[0]) == 2 and (s.frame(3)[0] >= 8).all()
    few = PointSampler(budget=1, step=4)  # more frames than points allowed: one point each, and it ends
    for i in range(3):
        few.add(i, mask, points=pts)
    assert [len(few.frame(i)[0]) for i in range(3)] == [1, 1, 1]
    dense = PointSampler(budget=64, step=1)  # 4096 grid points thinned to 64: still spread over the image
    dense.add(0, np.ones((64, 64), bool), points=np.zeros((64, 64, 3)))
    rows, cols, fields = dense.frame(0)
    assert dense.thin == 64 and len(rows) == 64 and fields["points"].shape == (64, 3)
    assert len(set(cols)) > 30 and len(set(rows)) > 30  # every 64th in raster order is one column
    assert len(set(zip(rows // 32, cols // 32))) == 4  # each quarter of the image keeps points
