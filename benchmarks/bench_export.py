"""Ground-truth export and video encoding speed at 256x512; prints JSON.

Renders a procedural trajectory (not timed), then times write_frames (PNG), export_ground_truth
(seconds per frame, everything of docs/formats.md "Ground-truth export", with the frames linked
into tum/rgb), write_video (frames/s, libx264 crf 18, each available backend) and the
translation's BackgroundFrameWriter (PNG frames and video, frames/s) with one PNG thread and with
its default, alternating, medians of --repeats; then reads the export back with
GroundTruthDataset in this process (samples/s, every field and image + depth only, medians).
Usage: python benchmarks/bench_export.py [--frames 100] [--height 256] [--width 512] [--repeats 3]
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

from sim2real.inference.export import export_ground_truth
from sim2real.inference.gt_dataset import GroundTruthDataset
from sim2real.inference.video import BackgroundFrameWriter, pyav_has_libx264, write_frames, write_video
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.procedural import generate_scene
from sim2real.scene.trajectory import make_trajectory


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    caster = RayCaster(generate_scene(0))
    traj = make_trajectory(caster, frames=args.frames, height=args.height, width=args.width, seed=1)
    gbuffers = [caster.render(c) for c in traj.cameras]
    frames = [to_uint8(reference_rendering(g)) for g in gbuffers]
    result = {
        "benchmark": "export_video",
        "machine": f"{platform.machine()} {os.cpu_count()} cores",
        "height": args.height,
        "width": args.width,
        "frames": args.frames,
    }
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "seq"
        t = time.perf_counter()
        names = write_frames(frames, out / "frames")
        result["write_frames_s_per_frame"] = round((time.perf_counter() - t) / args.frames, 5)
        t = time.perf_counter()
        export_ground_truth(gbuffers, out, fps=traj.fps, rgb_frames_rel=[f"frames/{n}" for n in names])
        result["export_s_per_frame"] = round((time.perf_counter() - t) / args.frames, 5)
        result["export_bytes_per_frame"] = int(
            sum(p.stat().st_size for p in out.rglob("*") if p.is_file() and "frames" not in p.parts) / args.frames
        )
        for backend in (["pyav"] if pyav_has_libx264() else []) + ["imageio"]:
            path = out / f"video_{backend}.mp4"
            t = time.perf_counter()
            write_video(frames, path, fps=traj.fps, backend=backend)
            dt = time.perf_counter() - t
            result[f"video_{backend}_frames_per_s"] = round(args.frames / dt, 1)
            result[f"video_{backend}_kib"] = round(path.stat().st_size / 1024, 1)
        writer = {"one_png_thread": 1, "default": None}
        times = {k: [] for k in writer}
        for r in range(args.repeats):
            for k, threads in writer.items():
                d = out / f"writer_{k}_{r}"
                d.mkdir()
                t = time.perf_counter()
                with BackgroundFrameWriter(d, d / "video.mp4", traj.fps, png_threads=threads) as w:
                    for f in frames:
                        w.put(f)
                times[k].append(time.perf_counter() - t)
        for k in writer:
            result[f"background_writer_{k}_frames_per_s"] = round(args.frames / statistics.median(times[k]), 1)
        readers = {"all_fields": GroundTruthDataset(out), "image_depth": GroundTruthDataset(out, fields=["image", "depth"])}
        times = {k: [] for k in readers}
        for _ in range(args.repeats):
            for k, data in readers.items():
                t = time.perf_counter()
                for i in range(len(data)):
                    data[i]
                times[k].append(time.perf_counter() - t)
        for k in readers:
            result[f"dataset_{k}_samples_per_s"] = round(args.frames / statistics.median(times[k]), 1)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
