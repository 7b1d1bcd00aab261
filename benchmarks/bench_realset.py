"""Throughput of real footage: ``sim2real realset`` frames/s per core, and the trainer's real
images/s per worker from a real set against a plain folder of full-size images; prints JSON.

Inputs are the user's own footage (not shipped), passed as paths:

    python benchmarks/bench_realset.py --video VIDEO.mp4 --frames FOLDER [--repeats 3] [--samples 60]

* ``realset``: :func:`sim2real.footage.build.build_realset` on the video (every frame: ``fps`` far
  above the video's) and on the folder of frames, ``repeats`` times each; frames/s per core is
  frames over the process's CPU seconds (PyAV decodes with threads; their time counts), beside
  the wall-clock rate, and PyAV's decode alone as the reference row.
* ``trainer``: ``RealImages.sample`` at 256x512 (scale 1.0-1.2, as training) in one thread (as a
  DataLoader worker runs), from the real set and from a plain folder of the same frames at full
  size (PNG: the video's frames written out as a user would today, and the folder's own files);
  images/s per worker = samples over CPU seconds, median of ``repeats``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import av
import cv2
import numpy as np
from PIL import Image
from threadpoolctl import threadpool_limits

from sim2real.data.real import RealImages
from sim2real.footage.build import Settings, build_realset


def _timed(fn) -> tuple[float, float]:
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def _realset_rate(src: str, base: Path, repeats: int, name: str) -> dict:
    walls, cpus, frames = [], [], 0
    for r in range(repeats):
        out = base / f"{name}_{r}"
        m = {}
        walls_cpu = _timed(lambda: m.update(build_realset([src], str(out), Settings(fps=1000.0, dup_distance=-1),
                                                          progress=False, log=lambda s: None)))
        walls.append(walls_cpu[0])
        cpus.append(walls_cpu[1])
        frames = m["kept"] + sum(m["dropped"].values())
    return {"frames": frames, "frames_per_s_wall": round(frames / statistics.median(walls), 2),
            "frames_per_s_per_core": round(frames / statistics.median(cpus), 2),
            "cpu_s_median": round(statistics.median(cpus), 3), "wall_s_median": round(statistics.median(walls), 3)}


def _decode_rate(video: str, repeats: int) -> dict:
    cpus, n = [], 0
    for _ in range(repeats):
        def run():
            nonlocal n
            with av.open(video) as c:
                s = c.streams.video[0]
                s.thread_type = "AUTO"
                n = sum(1 for f in c.decode(s) if f.to_ndarray(format="rgb24") is not None)
        cpus.append(_timed(run)[1])
    return {"frames": n, "frames_per_s_per_core": round(n / statistics.median(cpus), 2)}


def _sample_rate(pool: RealImages, samples: int, repeats: int) -> dict:
    rates = []
    with threadpool_limits(1):
        rng = np.random.default_rng(0)
        pool.sample(rng, 256, 512, 1.0, 1.2)  # masks loaded once per process, as in a worker
        for _ in range(repeats):
            _, cpu = _timed(lambda: [pool.sample(rng, 256, 512, 1.0, 1.2) for _ in range(samples)])
            rates.append(samples / cpu)
    return {"images": len(pool), "images_per_s_per_worker": round(statistics.median(rates), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", required=True, help="a video file (the 1080p one)")
    ap.add_argument("--frames", required=True, help="a folder of frames (the 854x480 ones)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--samples", type=int, default=60)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    res: dict = {"machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                             "python": platform.python_version(), "note": "shared machine: timings are noisy"}}
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        with av.open(args.video) as c:
            s = c.streams.video[0]
            res["video"] = {"size": [s.codec_context.height, s.codec_context.width], "codec": s.codec_context.name}
        res["realset_video"] = _realset_rate(args.video, base, args.repeats, "video")
        res["decode_only_video"] = _decode_rate(args.video, args.repeats)
        res["realset_frames"] = _realset_rate(args.frames, base, args.repeats, "frames")
        # plain folders of full-size frames, as training reads them today
        plain_video = base / "plain_video"
        plain_video.mkdir()
        with av.open(args.video) as c:
            for i, f in enumerate(c.decode(video=0)):
                Image.fromarray(f.to_ndarray(format="rgb24")).save(plain_video / f"{i:06d}.png")
        res["trainer_video_frames"] = {
            "realset": _sample_rate(RealImages(base / "video_0"), args.samples, args.repeats),
            "plain_full_size_png": _sample_rate(RealImages(plain_video, verify=False), args.samples, args.repeats)}
        res["trainer_frames"] = {
            "realset": _sample_rate(RealImages(base / "frames_0"), args.samples, args.repeats),
            "plain_full_size": _sample_rate(RealImages(args.frames, verify=False), args.samples, args.repeats)}
        # the start-up check a plain folder had at every start, now once per run (into its index)
        _, cpu = _timed(lambda: RealImages(plain_video, verify=True))
        res["plain_folder_check_s"] = {"images": len(RealImages(plain_video, verify=False)), "cpu_s": round(cpu, 3)}
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
