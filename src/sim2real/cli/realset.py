"""``sim2real realset``: make a real set (domain B) from the user's own footage.

    sim2real realset SRC [SRC ...] --out REAL [--height H] [--fps F] [--max-frames N]
                     [--held-out FRACTION] [--dup-distance BITS] [--min-content FRACTION]
                     [--labels DIR --label-map FILE [--class-table FILE]] [--format jpg|png] [--seed S]

SRC: video files (mp4, avi, mkv, mov, ...; ``VIDEO@START-END`` takes a time range, seconds or
[h:]mm:ss) and folders of frames (each sub-folder with frames is a source), mixed. Frames are
cropped to the endoscope's content area, masked where it has overlays, stored with their short
side at H, and filtered (dark, overexposed, near-duplicate, too little content); the split into
train and held-out is by source. ``REAL`` is what ``--real`` of train and evaluate takes
(docs/footage.md).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from sim2real.cli.args import counted, int_range, non_negative_float, positive_float, positive_int


def _fraction(text: str) -> float:
    v = non_negative_float(text)
    if v >= 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got '{text}'")
    return v


_distance = int_range(-1, 64)


def register(sub) -> None:
    p = sub.add_parser("realset", help="make a real set (domain B) from videos and folders of frames",
                       description=__doc__.replace("``", ""), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sources", nargs="+", metavar="SRC",
                   help="video files (VIDEO@START-END for a range) or frame folders")
    p.add_argument("--out", required=True, help="new output folder")
    p.add_argument("--height", type=positive_int, default=512,
                   help="short side of the stored frames, never enlarged (default 512: the largest training height "
                        "planned; a circular view needs about twice the crop height)")
    p.add_argument("--fps", type=positive_float, default=5.0, help="frames per second sampled from videos (default 5)")
    p.add_argument("--max-frames", type=positive_int, default=None, metavar="N",
                   help="at most N sampled frames per source")
    p.add_argument("--held-out", type=_fraction, default=0.2, metavar="FRACTION",
                   help="share of the sources held out from training (default 0.2; at least one of two or more)")
    p.add_argument("--dup-distance", type=_distance, default=4, metavar="BITS",
                   help="perceptual-hash distance (of 64 bits) up to which a frame is a near-duplicate "
                        "(default 4; -1 keeps them)")
    p.add_argument("--min-content", type=_fraction, default=0.25, metavar="FRACTION",
                   help="sources whose content area is below this share of the frame are dropped (default 0.25)")
    p.add_argument("--labels", default=None, metavar="DIR", help="class-id masks, mirroring the SRC folders' layout")
    p.add_argument("--label-map", default=None, metavar="FILE",
                   help="JSON: dataset class id (\"21\") or colour (\"#ff7272\") -> class name of the class table, or null")
    p.add_argument("--class-table", default=None, metavar="FILE",
                   help="class table JSON adding the user's own classes for --label-map (as scene import takes)")
    p.add_argument("--calibration", default=None, metavar="FILE",
                   help="the endoscope's OpenCV calibration (JSON: width, height, fx, fy, cx, cy, dist): frames are "
                        "undistorted first, and each source's pinhole intrinsics are reported")
    p.add_argument("--highlights", choices=("keep", "inpaint"), default="keep",
                   help="inpaint: find the specular highlights of every kept frame and paint them out (OpenCV "
                        "inpainting), so that a view-independent texture is not taught highlights that move with "
                        "the light; keep: store frames as they are (default)")
    p.add_argument("--format", choices=("jpg", "png"), default="jpg", help="stored frames (default jpg, quality 95)")
    p.add_argument("--seed", type=int, default=0, help="seed of the held-out choice (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.footage.build import Settings, build_realset  # only this command needs PyAV and OpenCV

    settings = Settings(height=args.height, fps=args.fps, max_frames=args.max_frames, held_out=args.held_out,
                        dup_distance=args.dup_distance, min_content=args.min_content, image_format=args.format,
                        labels=args.labels, label_map=args.label_map, class_table=args.class_table, seed=args.seed,
                        highlights=args.highlights, calibration=args.calibration)
    m = build_realset(args.sources, args.out, settings, progress=not args.quiet)
    for src in m["sources"]:
        drops = ", ".join(f"{k} {v}" for k, v in src["dropped"].items() if v) or "none"
        notes = f"{counted(src['own_mask_frames'], 'frame')} with a view of their own, " if src["own_mask_frames"] else ""
        if "highlights" in src:
            hl = src["highlights"]
            notes += f"highlights painted out: median {hl['median']:.1%}, max {hl['max']:.1%} of the content, "
        k = _crop_scale(Path(args.out), m, src)
        if k is not None:
            notes += f"1:2 crops up to {int(64 * k)}x{int(128 * k)} px unenlarged, "
        print(f"{src['id']}: {src['kind']} {src['frame_size'][1]}x{src['frame_size'][0]}, {src['shape']} view, "
              f"content {src['content_fraction']:.0%} (overlay {src['overlay_fraction']:.1%}), {notes}"
              f"{src['split']}: kept {src['kept']}, dropped {drops}")
        if "intrinsics" in src:
            fx, fy, cx, cy = src["intrinsics"]
            fov = "" if k is None else (f"; a 1:2 crop {int(128 * k)} px wide sees up to "
                                        f"{math.degrees(2 * math.atan(64 * k / fx)):.1f} degrees across")
            print(f"{src['id']}: undistorted; the stored frames' pinhole intrinsics: fx {fx:.1f}, fy {fy:.1f}, "
                  f"cx {cx:.1f}, cy {cy:.1f} px{fov}")
    drops = ", ".join(f"{k} {v}" for k, v in m["dropped"].items())
    labelled = sum(1 for f in m["frames"] if f["label"])
    print(f"kept {counted(m['kept'], 'frame')} ({labelled} labelled); dropped: {drops}; written to {args.out}")
    return 0


def _crop_scale(out: Path, manifest: dict, src: dict) -> float | None:
    """The scale k of the largest 1:2 window (64k x 128k px) inside the content mask of every kept
    frame of the source, as stored (the measure of the training's enlargement note, data/real.py);
    None when none is kept."""
    from sim2real.data.cover import ValidArea
    from sim2real.data.real_manifest import load_mask, mask_file

    ids = {f["mask"] for f in manifest["frames"] if f["source"] == src["id"]}
    if not ids:
        return None
    return min(ValidArea(load_mask(out / mask_file(i))).inscribed_scale(64, 128) for i in ids)
