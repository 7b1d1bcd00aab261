"""The weight-free realism measures: hand-computed cases, the null for sets of one distribution,
and a synthetic ladder of known defects ranked in order."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import stats

from sim2real.metrics.perturb import blurred, lined, specked
from sim2real.metrics.twosample import RandomFeatures, c2st, kid_unbiased, random_kid

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_kid_unbiased_by_hand():
    # d = 2, k(a, b) = (a.b / 2 + 1)^3
    x = np.array([[0.0, 0.0], [0.0, 0.0]])
    y = np.array([[2.0, 0.0], [2.0, 0.0]])
    # k(x, x') = 1, k(y, y') = (4/2 + 1)^3 = 27, k(x, y) = 1: 1 + 27 - 2 * 1
    assert kid_unbiased(x, y) == pytest.approx(26.0)
    e = np.eye(2)
    # off-diagonal k(e1, e2) = 1 in both sets; cross mean (2 * 1.5^3 + 2 * 1) / 4 = 2.1875
    assert kid_unbiased(e, e) == pytest.approx(1 + 1 - 2 * 2.1875)
    with pytest.raises(ValueError):
        kid_unbiased(x[:1], y)


def test_random_features_fixed_by_seed():
    a, b, c = RandomFeatures(5), RandomFeatures(5), RandomFeatures(6)
    assert all(np.array_equal(p.numpy(), q.numpy()) for p, q in zip(a.weights, b.weights))
    assert not np.array_equal(a.weights[0].numpy(), c.weights[0].numpy())
    # N(0, 2 / fan_in): the first layer's 3 * 9 = 27 inputs give a standard deviation of sqrt(2 / 27)
    assert float(a.weights[1].std()) == pytest.approx(np.sqrt(2 / (32 * 9)), rel=0.05)
    assert a.dim == 960


def tissue(n: int, rng: np.random.Generator, h: int = 48, w: int = 96) -> list[np.ndarray]:
    """Frames of one synthetic 'real' domain: a pink base, a mottled low-frequency pattern and
    fine grain, each frame drawn anew."""
    out = []
    for _ in range(n):
        low = cv2.GaussianBlur(rng.normal(0, 1, (h, w)), (0, 0), 3)
        low /= low.std() + 1e-9
        grain = rng.normal(0, 1, (h, w))
        v = 0.55 + 0.12 * low + 0.04 * grain
        rgb = np.stack([v + 0.25, v * 0.55, v * 0.5], -1)
        out.append(np.clip(rgb * 255, 0, 255).astype(np.uint8))
    return out


@pytest.fixture(scope="module")
def ladder():
    rng = np.random.default_rng(0)
    real, held, ceiling = tissue(40, rng), tissue(40, rng), tissue(40, rng)
    smooth = [cv2.GaussianBlur(f, (0, 0), 6) for f in tissue(40, rng)]  # an untranslated-looking a_ref
    r2 = np.random.default_rng(1)
    return real, {"real_held_out": held, "ceiling": ceiling, "blurred": [blurred(f) for f in ceiling],
                  "lined": [lined(f, r2, lines=4) for f in ceiling], "specked": [specked(f, r2) for f in ceiling],
                  "a_ref": smooth}


def test_random_kid_ranks_the_ladder(ladder):
    real, rows = ladder
    v = {name: random_kid(frames, real) for name, frames in rows.items()}
    defects = [v[k] for k in ("blurred", "lined", "specked", "a_ref")]
    # sets of one distribution sit at the null (about 0), far below every defect
    assert max(abs(v["real_held_out"]), abs(v["ceiling"])) < 0.5 * min(defects), v
    assert random_kid(real, real) == pytest.approx(random_kid(real, real))  # deterministic


def test_c2st_null_and_separation(ladder):
    real, rows = ladder
    same = c2st(rows["real_held_out"], real, seed=0)
    assert same["n_test"] == 40 and same["p_value"] > 0.01 and 0.2 <= same["accuracy"] <= 0.8, same
    for name in ("blurred",):  # the subtlest defect of the ladder for a classifier
        r = c2st(rows[name], real, seed=0)
        assert r["accuracy"] > same["accuracy"] and r["auc"] > 0.9, (name, r)
    # told apart completely: black vs white frames, 8 per set -> 4 + 4 held out, p = 0.5^8
    black, white = [np.zeros((16, 16, 3), np.uint8)] * 8, [np.full((16, 16, 3), 255, np.uint8)] * 8
    r = c2st(black, white, seed=0, steps=40)
    assert r["accuracy"] == 1.0 and r["auc"] == 1.0 and r["p_value"] == pytest.approx(0.5 ** 8)
    assert r["p_value"] == pytest.approx(stats.binomtest(8, 8, 0.5, alternative="greater").pvalue)
