"""The realism stage of ``sim2real evaluate`` (:mod:`sim2real.inference.stages` runs the others):
FID/KID with user-given Inception weights, the proxy and the detail ratio, and the measures that
need no downloaded weights (the C2ST, KID in random-network features). Every measure has its
``real_held_out`` row: what real frames score, one half of the real images against the other.
"""

from __future__ import annotations

import time
import warnings
from typing import TYPE_CHECKING, Sequence

import numpy as np

from sim2real.inference.jobs import Jobs
from sim2real.inference.realimages import real_halves, to_nchw
from sim2real.metrics.realism import fid_kid, proxy_colour_texture_distance, proxy_stats
from sim2real.metrics.twosample import RANDOM_NET_SEED, RandomFeatures, c2st, random_kid
from sim2real.threads import one_torch_thread

if TYPE_CHECKING:
    from sim2real.inference.stages import Say, ViewSet


def realism_stage(vs: ViewSet, real_imgs: Sequence[np.ndarray], inception, status: dict, s,
                  rows_shown: Sequence[str], say: Say = lambda m: None, device="cpu") -> dict:
    """FID/KID (with the user's Inception weights, else ``None`` and the reason), the proxy, the
    detail ratio and the weight-free measures (:func:`weight_free_realism`) of every row. Returns
    ``{"rows": {row: {...}}, "fid", "fid_info", "proxy", "real_held_out", "reason", "measures"}``,
    ``real_held_out`` holding FID, KID and the proxy of one half of the real images against the
    other (None where a half has too few images or no weights are given)."""
    realism: dict[str, dict] = {r: {} for r in rows_shown}
    gen = vs.scored["model"]
    real_t = to_nchw(real_imgs)
    reason = None
    fid = {"fid": None, "kid_mean": None, "kid_std": None}
    fid_info = {"n_real": len(real_imgs), "n_gen": len(gen), "kid_subset_size": None, "kid_subsets": s.kid_subsets,
                "weights": status.get("path"), "variants": list(vs.variants)}
    ref, held = real_halves(real_imgs, s.seed)
    ref_t, held_t = (to_nchw(ref), to_nchw(held)) if ref and held else (None, None)
    fid_real = {"fid": None, "kid": None}  # FID/KID's real row: one half of the real images against the other
    if inception is None:
        reason = status["reason"]
    elif len(gen) < 2 or len(real_imgs) < 2:
        reason = f"FID/KID need at least 2 images per set (got {len(real_imgs)} real, {len(gen)} generated)"
    else:
        def scores(images, reference) -> dict:
            with warnings.catch_warnings():  # torchmetrics warns that KID keeps its features: known, bounded here
                warnings.filterwarnings("ignore", message=".*will save all extracted features in buffer.*")
                return fid_kid(images, reference, inception, kid_subset_size=s.kid_subset_size,
                               kid_subsets=s.kid_subsets, batch_size=max(s.batch, 16), seed=s.seed)

        say(f"FID/KID: Inception features of {len(real_imgs)} real and {len(gen)} images per row")
        for row in rows_shown:
            r = scores(to_nchw(vs.scored[row]), real_t)
            vals = _finite({"fid": r["fid"], "kid_mean": r["kid_mean"], "kid_std": r["kid_std"]})
            realism[row].update(fid=vals["fid"], kid=vals["kid_mean"])
            if row == "model":
                fid = vals
                fid_info.update(kid_subset_size=r["kid_subset_size"])
                bad = [k for k, v in vals.items() if v is None]
                if bad:
                    reason = f"{', '.join(bad)} not finite (too few images for a {r['num_features']}-d covariance?)"
        if len(ref) >= 2 and len(held) >= 2:
            r = scores(held_t, ref_t)
            fid_real = _finite({"fid": r["fid"], "kid": r["kid_mean"]})
    proxy = None
    real_stats = proxy_stats(real_t)  # once for every row
    for row in rows_shown:
        p = proxy_colour_texture_distance(to_nchw(vs.scored[row]), real_t, real_stats=real_stats)
        if row == "model":
            proxy = p
        realism[row]["proxy"] = p["proxy_colour_texture_distance"]
        # detail: the row's mean grey gradient as a share of the real images' (1 = as detailed)
        g_real = p["proxy_grad_mean_real"]
        realism[row]["detail"] = p["proxy_grad_mean_gen"] / g_real if g_real > 0 else None
    # the proxy's scale: what real frames score, one half of the real images against the other
    proxy_real = (proxy_colour_texture_distance(held_t, ref_t)["proxy_colour_texture_distance"]
                  if held_t is not None else None)
    measures = weight_free_realism(vs.scored, real_imgs, s, rows_shown, device, say)
    for name, m in measures.items():
        for row in rows_shown:
            realism[row][name] = m["rows"].get(row)
    real_row = {**fid_real, "proxy": proxy_real}
    return {"rows": realism, "fid": fid, "fid_info": fid_info, "proxy": proxy, "real_held_out": real_row,
            "reason": reason, "measures": measures}


def _finite(values: dict) -> dict:
    """Non-finite values (a covariance of too few images) -> None."""
    return {k: (v if np.isfinite(v) else None) for k, v in values.items()}


def device_type(device) -> str:
    return getattr(device, "type", str(device).split(":")[0])


def weight_free_realism(scored: dict[str, list], real_imgs: Sequence[np.ndarray], s, rows_shown: Sequence[str],
                        device="cpu", say: Say = lambda m: None) -> dict:
    """The realism measures that need no downloaded weights (:mod:`sim2real.metrics.twosample`),
    ``{name: {"better", "null", "rows": {row: value}, "details", "seconds", "reason"}}``.

    The real images are split in halves (seeded): every row is compared with the reference half,
    and the held-out half is the ``real_held_out`` row, the value of real frames themselves (the
    null). ``c2st`` is the classifier test's held-out AUC (0.5: indistinguishable from real; its
    accuracy and binomial p-value are in ``details``: the AUC ranked the validation ladder at
    every seed, the accuracy at the logit threshold 0 did not; docs/evaluation.md),
    ``random_kid`` the unbiased KID in a fixed random network's features (0: as real).
    """
    out: dict[str, dict] = {}
    ref, held = real_halves(real_imgs, s.seed)
    sets = {**{r: scored[r] for r in rows_shown}, "real_held_out": held}
    small = min(len(ref), min(len(v) for v in sets.values()))
    specs = [("random_kid", 0.0, s.realism_kid, 2), ("c2st", 0.5, s.c2st_steps > 0, 4)]
    for name, null, enabled, need in specs:
        entry = {"better": "lower", "null": null, "rows": {r: None for r in sets}, "details": {}, "seconds": 0.0,
                 "reason": None}
        out[name] = entry
        if not enabled:
            entry["reason"] = ("off by default: it did not rank blurred frames below real ones in the validation "
                               "(docs/evaluation.md)" if name == "random_kid" else "switched off in the settings")
            continue
        if small < need:
            entry["reason"] = (f"needs at least {need} frames per set and {need} real images in each half "
                               f"(got {small})")
            continue
        say(f"realism: {name} of {len(sets)} rows against {len(ref)} real images")
        t0 = time.perf_counter()
        if name == "random_kid":
            net = RandomFeatures(RANDOM_NET_SEED).to(device)
            for row, frames in sets.items():
                entry["rows"][row] = random_kid(frames, ref, net=net, device=device)
        else:
            # one test per row, each on one torch thread (held here for all of them), in parallel
            # threads: each row's classifier is seeded alike and trains alone, so the figures are
            # those of one thread
            with one_torch_thread(), Jobs(None if device_type(device) == "cpu" else 1) as jobs:
                tests = {row: jobs.submit(c2st, frames, ref, seed=s.seed, steps=s.c2st_steps, device=device)
                         for row, frames in sets.items()}
                for row, f in tests.items():
                    entry["rows"][row] = f.result()["auc"]
                    entry["details"][row] = f.result()
        entry["seconds"] = time.perf_counter() - t0
    return out


