"""sim2real.scene.tum.read_tum: the one reader of TUM pose rows (trajectories, exported poses)."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.errors import UserError
from sim2real.scene.tum import read_tum


def test_rows_and_comments(tmp_path):
    s = np.sqrt(0.5)
    f = tmp_path / "p.txt"
    f.write_text(f"# width 32\n\n  # fps 5\n1.5 10 20 30 0 0 {s} {s}\n")
    comments, poses = read_tum(f)
    assert comments == [(1, "# width 32"), (3, "# fps 5")]
    (t, T), = poses
    assert t == 1.5
    # 90 degrees about z: x -> y, y -> -x (hand-written, not from the code under test)
    np.testing.assert_allclose(T[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_array_equal(T[:3, 3], [10, 20, 30])
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


@pytest.mark.parametrize("row,words", [
    ("0 1 2 3 0 0 0", "p.txt:2: expected 8 numbers"),
    ("0 1 2 3 0 0 0 nan", "p.txt:2: expected 8 numbers"),
    ("0 1 2 3 0 0 0 x", "p.txt:2: expected 8 numbers"),
    ("0 1 2 3 0 0 0 1.1", "p.txt:2: quaternion is not of unit length"),
])
def test_bad_rows_name_their_line(tmp_path, row, words):
    f = tmp_path / "p.txt"
    f.write_text(f"0 0 0 0 0 0 0 1\n{row}\n")
    with pytest.raises(UserError, match=words):
        read_tum(f)


def test_unreadable_file_is_named(tmp_path):
    with pytest.raises(UserError, match="cannot read trajectory"):
        read_tum(tmp_path / "none.txt", "trajectory")
