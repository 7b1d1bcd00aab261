"""``sim2real evaluate``: FID/KID, Dice, OF error, ORB-k and the revisit protocol for a trained run.

    sim2real evaluate RUN --scenes SCENE_DIR... --real DIR --out DIR
                      [--trajectory FILE... (one per scene) | --frames 100] [--views 64]
    sim2real evaluate --frames DIR|VIDEO --trajectory FILE --scene SCENE_DIR --real DIR --out DIR
                      [--fid-weights PATH] [--device auto|cpu|cuda] [--precision auto|fp32|bf16] [--compile] [--checkpoint PATH]
                      [--seg-iterations 200] [--seg-size 32x64] [--seg-seeds 5] [--max-real 500] [--batch 8] [--seed 0]

The second form evaluates a video made by any tool along the trajectory of the scene
(:mod:`sim2real.inference.external`). Writes DIR/metrics.json, DIR/report.md, DIR/report.html, DIR/plots/, DIR/samples/, DIR/videos/
(docs/formats.md, "Evaluation").
"""

from __future__ import annotations

import argparse
import sys

from sim2real.cli.args import (
    EMULATED_BF16,
    add_compile_arg,
    add_motion_args,
    add_precision_arg,
    add_seg_iterations_arg,
    motion_kwargs,
    non_negative_int,
    positive_float,
    positive_int,
)


def _size(text: str) -> tuple[int, int]:
    try:
        h, w = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HEIGHTxWIDTH, e.g. 128x256, got '{text}'") from None
    if h < 1 or w < 1:
        raise argparse.ArgumentTypeError(f"expected a positive HEIGHTxWIDTH, got '{text}'")
    return h, w


def _frames(text: str) -> int | str:
    """A frame count, or a path (a folder of frames or a video)."""
    if text.isdigit():
        return positive_int(text)
    return text


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="the paper's realism and consistency metrics, with a report")
    p.add_argument("run", metavar="RUN", nargs="?",
                   help="training run folder (uses RUN/checkpoints/last.pt); none with --frames DIR|VIDEO")
    p.add_argument("--scenes", "--scene", nargs="+", required=True, metavar="SCENE_DIR",
                   help="scene folders the run was trained on (with --frames DIR|VIDEO: the one scene of the video)")
    p.add_argument("--real", required=True, metavar="DIR",
                   help="real images: DIR/images/ (+ DIR/labels/ for Dice) or a folder of PNG/JPEG files")
    p.add_argument("--out", required=True, metavar="DIR", help="new or empty output folder")
    p.add_argument("--frames", type=_frames, default=100, metavar="N|DIR|VIDEO",
                     help="frames of each generated trajectory (default 100); or a folder of frames or a video made "
                          "by any tool along --trajectory FILE, to evaluate instead of a run")
    p.add_argument("--trajectory", nargs="+", metavar="FILE", help="one trajectory file per scene (in --scenes order)")
    p.add_argument("--views", type=positive_int, default=64, help="random translated views for FID/KID and Dice (default 64)")
    p.add_argument("--fid-weights", metavar="PATH",
                   help="FID Inception weights (pt_inception-2015-12-05-6726825d.pth); default $SIM2REAL_FID_WEIGHTS")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    add_precision_arg(p)
    add_compile_arg(p)
    p.add_argument("--checkpoint", metavar="PATH", help="checkpoint file instead of RUN/checkpoints/last.pt")
    p.add_argument("--batch", type=positive_int, default=8, help="frames per network call (default 8)")
    p.add_argument("--seed", type=non_negative_int, default=0)
    p.add_argument("--max-real", type=positive_int, default=500, help="real images used for FID/KID (default 500)")
    add_seg_iterations_arg(p)
    p.add_argument("--seg-size", type=_size, default=(32, 64), metavar="HxW", help="segmenter image size (default 32x64)")
    p.add_argument("--orb-features", type=positive_int, default=1000)
    p.add_argument("--orb-max-k", type=positive_int, default=20, help="ORB curve up to this k (default 20)")
    p.add_argument("--threshold-mm", type=positive_float, default=1.0, help="ORB match correctness threshold (default 1 mm)")
    p.add_argument("--workers", type=positive_int, help="ray-casting processes (default: automatic)")
    add_motion_args(p)
    p.add_argument("--no-anchors", action="store_true", help="skip the ceiling and floor rows (faster, uncalibrated)")
    p.add_argument("--seg-seeds", type=positive_int, default=5, help="liver U-Nets whose Dice is averaged (default 5)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars or messages")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.engine.device import resolve_device
    from sim2real.engine.precision import emulated_bf16
    from sim2real.errors import UserError
    from sim2real.inference.evaluate import EvalSettings, evaluate

    video = args.frames if isinstance(args.frames, str) else None
    if video is None and args.run is None:
        raise UserError("give a run folder RUN, or a video to evaluate with --frames DIR|VIDEO")
    if video is not None and args.run is not None:
        raise UserError("give either a run folder RUN or --frames DIR|VIDEO, not both")
    if video is not None and args.precision != "auto":
        raise UserError("--precision sets a run's network arithmetic; --frames DIR|VIDEO evaluates a video without one")
    if video is not None and args.compile:
        raise UserError("--compile compiles a run's networks; --frames DIR|VIDEO evaluates a video without one")
    if video is not None and (not args.trajectory or len(args.trajectory) != 1 or len(args.scenes) != 1):
        raise UserError("--frames DIR|VIDEO needs exactly one --trajectory FILE and one --scenes DIR (the video's path)")
    if video is None and args.trajectory is not None and args.frames != 100:
        raise UserError("give either --trajectory FILE... or --frames N, not both")
    s = EvalSettings(views=args.views, frames=100 if video else args.frames, batch=args.batch, seed=args.seed, max_real=args.max_real,
                     seg_iterations=args.seg_iterations, seg_height=args.seg_size[0], seg_width=args.seg_size[1],
                     orb_features=args.orb_features, orb_max_k=args.orb_max_k, threshold_mm=args.threshold_mm,
                     workers=args.workers, anchors=not args.no_anchors, seg_seeds=args.seg_seeds,
                     trajectory=motion_kwargs(args))
    if video is not None:
        from sim2real.inference.external import evaluate_frames

        m = evaluate_frames(video, args.scenes[0], args.trajectory[0], args.real, args.out, settings=s,
                            fid_weights=args.fid_weights, device=args.device, progress=not args.no_progress)
    else:
        if emulated_bf16(resolve_device(args.device), args.precision == "bf16"):
            print(EMULATED_BF16, file=sys.stderr)
        m = evaluate(args.run, args.scenes, args.real, args.out, trajectories=args.trajectory, settings=s,
                     fid_weights=args.fid_weights, device=args.device, checkpoint=args.checkpoint,
                     precision=args.precision, compile=args.compile, progress=not args.no_progress)

    def f(v, fmt="{:.4g}"):
        return "n/a" if v is None else fmt.format(v)

    orb = "  ".join(f"ORB-{k} {f(e['accuracy'], '{:.1%}')} ({f(e['mean_correct'], '{:.1f}')})" for k, e in m["orb"].items())
    print(f"FID {f(m['fid'])}  KID {f(m['kid_mean'])}  Dice {f(m['dice'])}  OF {f(m['of_error'])}  {orb}")
    print(f"metrics and report written to {args.out} (metrics.json, report.md, report.html)")
    return 0
