"""Seconds per 256x512 frame pair of the temporal-consistency metrics; prints JSON.

    PYTHONPATH=src python benchmarks/bench_metrics.py [--repeats 5] [--inception]

Synthetic frames: a blurred random RGB texture and the same texture shifted 3 px (a fronto-
parallel plane 0.5 mm/px for the ORB ground truth). Reports the median over ``--repeats`` runs:
``of_error`` (Farnebäck + error), ``orb_accuracy`` (ORB on both frames, cross-checked matching,
3D check). ``--inception`` adds the FID Inception forward time per image (random weights, batch 8).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import cv2
import numpy as np

from sim2real.metrics.consistency import of_error, orb_accuracy

H, W = 256, 512


def _median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--inception", action="store_true")
    args = ap.parse_args()

    rng = np.random.default_rng(0)
    big = cv2.GaussianBlur(rng.random((H, W + 10, 3)).astype(np.float32), (0, 0), 1.5)
    big = (255 * (big - big.min()) / (big.max() - big.min())).astype(np.uint8)
    a, b = big[:, 5:5 + W], big[:, 2:2 + W]  # content moves 3 px right
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 3.0
    r, c = np.mgrid[0:H, 0:W].astype(np.float64)
    pa = np.stack([c * 0.5, r * 0.5, np.full((H, W), 100.0)], -1)
    pb = np.stack([(c - 3) * 0.5, r * 0.5, np.full((H, W), 100.0)], -1)
    valid = np.ones((H, W), bool)

    out = {
        "frame_size": [H, W],
        "repeats": args.repeats,
        "cpu_count": os.cpu_count(),
        "opencv_threads": cv2.getNumThreads(),
        "platform": platform.platform(),
        "of_error_s_per_pair": _median_seconds(lambda: of_error(flow, a, b, valid), args.repeats),
        "orb_accuracy_s_per_pair": _median_seconds(lambda: orb_accuracy(a, b, pa, pb, valid, valid), args.repeats),
        "check_of_error_px": of_error(flow, a, b, valid),
        "check_orb": orb_accuracy(a, b, pa, pb, valid, valid),
    }
    if args.inception:
        import torch

        from sim2real.metrics.inception import FIDInceptionV3

        net = FIDInceptionV3()
        x = torch.rand(8, 3, H, W)
        with torch.no_grad():
            out["fid_inception_s_per_image"] = _median_seconds(lambda: net(x), max(1, args.repeats // 2)) / 8
        out["torch_threads"] = torch.get_num_threads()
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
