r"""Realism measures that need no downloaded weights: two-sample tests between a set of frames and
the real images.

* :func:`random_kid`: the unbiased KID (squared MMD with the cubic polynomial kernel, Bińkowski
  et al. 2018) in the features of a **fixed-seed random CNN** (:class:`RandomFeatures`).
  Random-network features rank generative models close to trained ones (Lee et al., "Do
  generative models' evaluation need pretrained features?", AAAI 2023). The weights are drawn
  with numpy's PCG64 from a fixed seed, so they are the same on every machine and torch version.
* :func:`c2st`: a classifier two-sample test (Lopez-Paz & Oquab, "Revisiting classifier
  two-sample tests", ICLR 2017): a small CNN learns, on half of each set, to tell real frames
  from the others; its accuracy on the other half is 0.5 when the sets are alike (the binomial
  null) and 1 when it always tells them apart.

Frames are uint8 RGB ``(H, W, 3)`` numpy arrays of one size (the evaluation's size).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from scipy import stats
from torch import nn
from torch.nn import functional as F

from sim2real.threads import TORCH_RNG_LOCK, one_torch_thread

RANDOM_NET_SEED = 20230207
"""Seed of the random feature network's weights (fixed: part of the measure's definition)."""


def to_float(frames: Sequence[np.ndarray], device="cpu") -> torch.Tensor:
    """uint8 (H, W, 3) frames -> float (N, 3, H, W) in [0, 1]."""
    x = torch.from_numpy(np.stack([np.asarray(f) for f in frames])).permute(0, 3, 1, 2)
    return x.to(device=device, dtype=torch.float32).div_(255.0).contiguous()


# --- KID in random-network features --------------------------------------------------------------


class RandomFeatures(nn.Module):
    """Four 3x3 stride-2 conv + ReLU stages (32, 64, 128, 256 channels), weights N(0, 2 / fan_in)
    (He) from numpy's PCG64 with ``seed``, no biases. The feature of an image is the mean and the
    standard deviation over positions of every stage's channels (960 values): colour (first
    stage) and texture energy at four scales."""

    widths = (32, 64, 128, 256)

    def __init__(self, seed: int = RANDOM_NET_SEED):
        super().__init__()
        rng = np.random.default_rng(seed)
        c_in = 3
        self.weights = nn.ParameterList()
        for c in self.widths:
            w = rng.normal(0.0, np.sqrt(2.0 / (c_in * 9)), (c, c_in, 3, 3)).astype(np.float32)
            self.weights.append(nn.Parameter(torch.from_numpy(w), requires_grad=False))
            c_in = c

    @property
    def dim(self) -> int:
        return 2 * sum(self.widths)

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = (x - 0.5) / 0.25  # images in [0, 1] -> roughly zero-mean, unit-scale inputs
        feats = []
        for w in self.weights:
            x = F.relu(F.conv2d(x, w, stride=2, padding=1))
            flat = x.flatten(2)
            feats += [flat.mean(2), flat.std(2)]
        return torch.cat(feats, 1)


def features(frames: Sequence[np.ndarray], net: nn.Module, batch: int = 16) -> np.ndarray:
    """(N, d) float64 features of uint8 frames through ``net`` (on its device)."""
    dev = next(net.parameters()).device
    out = [net(to_float(frames[i:i + batch], dev)).double().cpu().numpy() for i in range(0, len(frames), batch)]
    return np.concatenate(out) if out else np.zeros((0, getattr(net, "dim", 0)))


def kid_unbiased(fx: np.ndarray, fy: np.ndarray) -> float:
    r"""Unbiased squared MMD between feature sets ``fx`` (m, d) and ``fy`` (n, d) with the cubic
    polynomial kernel :math:`k(a, b) = (a^\top b / d + 1)^3` (the KID of Bińkowski et al. 2018):

    .. math::
        \widehat{\mathrm{MMD}}^2_u = \frac{1}{m(m-1)} \sum_{i \ne j} k(x_i, x_j)
          + \frac{1}{n(n-1)} \sum_{i \ne j} k(y_i, y_j) - \frac{2}{mn} \sum_{i, j} k(x_i, y_j)

    Its expectation is 0 when both sets come from one distribution (it can then be slightly
    negative); it needs m, n >= 2."""
    fx, fy = np.asarray(fx, np.float64), np.asarray(fy, np.float64)
    m, n = len(fx), len(fy)
    if m < 2 or n < 2:
        raise ValueError(f"KID needs at least 2 samples per set, got {m} and {n}")
    d = fx.shape[1]
    kxx = (fx @ fx.T / d + 1) ** 3
    kyy = (fy @ fy.T / d + 1) ** 3
    kxy = (fx @ fy.T / d + 1) ** 3
    return float((kxx.sum() - np.trace(kxx)) / (m * (m - 1)) + (kyy.sum() - np.trace(kyy)) / (n * (n - 1))
                 - 2 * kxy.mean())


def standardise(reference: np.ndarray, *others: np.ndarray) -> list[np.ndarray]:
    r"""Every set centred on the reference set's mean feature and divided by one scalar, the
    reference's root mean feature variance :math:`s = \sqrt{\tfrac1d \sum_k \mathrm{var}_k}`: the
    reference then has mean 0 and mean variance 1 per feature. One scalar, not a deviation per
    feature: a feature that the reference hardly varies must not blow up into the cubic kernel."""
    mu = reference.mean(0)
    s = float(np.sqrt(reference.var(0).mean()))
    s = s if s > 1e-12 else 1.0
    return [(a - mu) / s for a in (reference,) + others]


def random_kid(gen: Sequence[np.ndarray], real: Sequence[np.ndarray], seed: int = RANDOM_NET_SEED,
               net: RandomFeatures | None = None, device="cpu") -> float:
    """:func:`kid_unbiased` of ``gen`` vs ``real`` in :class:`RandomFeatures` (seed ``seed``),
    both sets :func:`standardise`-d with the real set's statistics. Lower is better; about 0 for
    two sets of one distribution."""
    net = net or RandomFeatures(seed).to(device)
    fr, fg = standardise(features(real, net), features(gen, net))
    return kid_unbiased(fg, fr)


# --- classifier two-sample test ------------------------------------------------------------------


class C2STNet(nn.Module):
    """Three 3x3 stride-2 conv + ReLU stages (16, 32, 64), global average and max pooling, a linear
    logit: small enough to train in seconds on a CPU, fully convolutional so that it trains on
    crops and tests on whole frames."""

    def __init__(self):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(3, 16, 3, 2, 1), nn.ReLU(), nn.Conv2d(16, 32, 3, 2, 1), nn.ReLU(),
                                  nn.Conv2d(32, 64, 3, 2, 1), nn.ReLU())
        self.head = nn.Linear(128, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.body((x - 0.5) / 0.25).flatten(2)
        return self.head(torch.cat([h.mean(2), h.amax(2)], 1))[:, 0]


def _crops(x: torch.Tensor, size: int, rng: np.random.Generator) -> torch.Tensor:
    n, _, h, w = x.shape
    ch, cw = min(size, h), min(size, w)
    out = []
    for i in range(n):
        y0, x0 = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
        c = x[i, :, y0:y0 + ch, x0:x0 + cw]
        out.append(c.flip(-1) if rng.random() < 0.5 else c)
    return torch.stack(out)


def c2st(gen: Sequence[np.ndarray], real: Sequence[np.ndarray], seed: int = 0, steps: int = 150, batch: int = 16,
         crop: int = 48, lr: float = 2e-3, device="cpu") -> dict:
    r"""Classifier two-sample test of ``gen`` against ``real``.

    Both sets are cut to the smaller one's size ``n`` (a seeded subset) and each is split in
    halves; :class:`C2STNet` trains ``steps`` Adam steps on random ``crop``-pixel crops (flipped
    at random) of the training halves, ``batch / 2`` of each set per step, and scores the whole
    frames of the held-out halves, ``t`` of each set (``2t`` frames in all). Returns

    * ``accuracy`` = share of the ``2t`` held-out frames on the right side of the threshold
      halfway between the median logits of the training halves' whole frames;
    * ``p_value`` = :math:`P(X \ge \text{correct})` for :math:`X \sim \mathrm{Binomial}(2t, 1/2)`,
      the chance of doing as well with sets of one distribution (Lopez-Paz & Oquab 2017);
    * ``auc`` = Mann-Whitney :math:`U / t^2`: the probability that a held-out ``gen`` frame
      scores above a held-out ``real`` one (0.5 under the null, 1 when always told apart);
    * ``n_test`` = ``2t``.

    Cost: ``steps * batch`` crops of ``crop``² pixels; the defaults (150 steps of 16 crops of 48
    pixels) took 1.5 s of one CPU core on the 2-core dev machine (32 frames of 128x256 against
    100 real ones), 32 crops of 64 pixels 5.7 s.

    Lower accuracy is better (0.5: indistinguishable). Seeded: torch's and numpy's generators
    are derived from ``seed`` and the caller's torch RNG is left as it was.
    """
    n = min(len(gen), len(real))
    if n < 4:
        raise ValueError(f"the classifier test needs at least 4 frames per set, got {len(gen)} and {len(real)}")
    rng = np.random.default_rng(seed)
    g_idx, r_idx = rng.permutation(len(gen))[:n], rng.permutation(len(real))[:n]
    half = n // 2
    g, r = to_float([gen[i] for i in g_idx], device), to_float([real[i] for i in r_idx], device)
    g_tr, g_te, r_tr, r_te = g[:half], g[half:], r[:half], r[half:]
    t = min(len(g_te), len(r_te))
    g_te, r_te = g_te[:t], r_te[:t]
    with one_torch_thread():
        # only the initialisation draws from torch's global generator (the crops and batches come
        # from rng): held under the lock, so that tests of several rows can train in threads
        with TORCH_RNG_LOCK, torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            net = C2STNet().to(device)
        opt = torch.optim.Adam(net.parameters(), lr=lr)
        b = max(1, batch // 2)
        target = torch.cat([torch.ones(b), torch.zeros(b)]).to(device)
        for _ in range(steps):
            xg = _crops(g_tr[torch.from_numpy(rng.integers(0, len(g_tr), b))], crop, rng)
            xr = _crops(r_tr[torch.from_numpy(rng.integers(0, len(r_tr), b))], crop, rng)
            loss = F.binary_cross_entropy_with_logits(net(torch.cat([xg, xr])), target)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        net.eval()
        with torch.no_grad():
            sg, sr, tg, tr = (torch.cat([net(x[i:i + 16]) for i in range(0, len(x), 16)]).cpu().numpy()
                              for x in (g_te, r_te, g_tr, r_tr))
    # The threshold between the two training halves' median whole-frame logits, not 0: trained
    # on crops, the net's whole-frame logits shift (its max pooling covers more pixels), and on
    # another CPU the same seed gave the ladder's blurred row AUC 1.0 at accuracy 0.5 with 0.
    # Set on the training frames only, it leaves the binomial null of the held-out ones intact.
    threshold = 0.5 * (float(np.median(tg)) + float(np.median(tr)))
    correct = int((sg > threshold).sum() + (sr <= threshold).sum())
    u = stats.mannwhitneyu(sg, sr, alternative="two-sided").statistic
    return {"accuracy": correct / (2 * t), "p_value": float(stats.binom.sf(correct - 1, 2 * t, 0.5)),
            "auc": float(u / (t * t)), "n_test": 2 * t, "steps": int(steps)}
