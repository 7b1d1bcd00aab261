"""``sim2real benchmark``: Table 1 of the paper in one command (sim2real/comparison/run.py).

    sim2real benchmark --out DIR [--methods NAME...] [--minutes-per-method M | --iterations N]
                       [--scenes DIR... --real DIR] [--trajectory FILE...] [--preset P] [--seed S] [--resume]

Without data flags it makes the embedded data itself, as the demo does (with stand-in real
sequences when a video method is compared). The budget is wall-clock minutes or iterations per
method; the table records both.
"""

from __future__ import annotations

import argparse

from sim2real.cli.args import (
    add_motion_args,
    add_seg_iterations_arg,
    motion_kwargs,
    non_negative_int,
    positive_float,
    positive_int,
)
from sim2real.presets import METHOD_PRESETS, PRESETS

DEFAULT_MINUTES = 20.0


def register(sub) -> None:
    p = sub.add_parser("benchmark", help="train, translate and evaluate every method on the same data (Table 1)")
    p.add_argument("--out", required=True, help="new output directory (or the benchmark to --resume)")
    p.add_argument("--methods", nargs="+", default=list(METHOD_PRESETS), metavar="NAME",
                   help=f"methods to compare (default: all: {', '.join(METHOD_PRESETS)})")
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--minutes-per-method", type=positive_float, default=None,
                        help=f"wall-clock training budget per method (default {DEFAULT_MINUTES:g})")
    budget.add_argument("--iterations", type=positive_int, default=None, help="training iterations per method")
    p.add_argument("--scenes", nargs="+", metavar="DIR", help="simulated scene folders (default: embedded procedural)")
    p.add_argument("--real", metavar="DIR", help="real images (with sequences/ for the video methods)")
    p.add_argument("--trajectory", nargs="+", metavar="FILE", help="test trajectories, one per scene")
    p.add_argument("--preset", choices=tuple(PRESETS), default=None,
                   help="default: paper on a GPU, cpu on a CPU (sim2real/presets.py)")
    p.add_argument("--seed", type=non_negative_int, default=0)
    p.add_argument("--seeds", type=positive_int, default=1,
                   help="trainings per method with seeds SEED, SEED+1, ... on the same data and test paths "
                        "(default 1; a --resume may raise it)")
    p.add_argument("--seeds-for", nargs="+", metavar="NAME", default=None,
                   help="the methods trained --seeds times (default: every method)")
    p.add_argument("--frames", type=positive_int, default=100, help="frames of a generated test trajectory")
    p.add_argument("--eval-views", type=positive_int, default=32, help="random views for the realism metrics")
    add_seg_iterations_arg(p)
    p.add_argument("--real-images", type=positive_int, default=200, help="embedded stand-in real images")
    p.add_argument("--real-sequences", type=non_negative_int, default=4, help="embedded stand-in real sequences")
    p.add_argument("--sequence-frames", type=positive_int, default=30, help="frames per embedded real sequence")
    p.add_argument("--fid-weights", default=None, help="pt_inception-2015-12-05 weights for FID/KID (optional)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--parallel", type=positive_int, default=1,
                   help="methods trained at once, each on an equal share of the cores (default 1)")
    p.add_argument("--resume", action="store_true", help="continue a killed benchmark (finished methods are kept)")
    add_motion_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.comparison.run import BenchmarkSettings, run_benchmark

    minutes = args.minutes_per_method
    if minutes is None and args.iterations is None:
        minutes = DEFAULT_MINUTES
    s = BenchmarkSettings(methods=list(args.methods), minutes=minutes, iterations=args.iterations, preset=args.preset,
                          seed=args.seed, seeds=args.seeds, seeds_for=args.seeds_for, device=args.device,
                          real_images=args.real_images,
                          sequences=args.real_sequences, sequence_frames=args.sequence_frames, frames=args.frames,
                          eval_views=args.eval_views, seg_iterations=args.seg_iterations,
                          trajectory=motion_kwargs(args), parallel=args.parallel)
    table = run_benchmark(args.out, s, scenes=args.scenes, real=args.real, trajectories=args.trajectory,
                          resume=args.resume, fid_weights=args.fid_weights)
    print(f"benchmark written to {args.out}: table.md, table.json, report.html, videos/ "
          f"({len(table['methods'])} methods)")
    return 0
