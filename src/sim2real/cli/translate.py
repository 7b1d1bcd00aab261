"""``sim2real translate``: render a camera trajectory (or a views folder) through a trained run.

    sim2real translate RUN --scene SCENE --trajectory FILE --out DIR [--batch B] [--device auto|cpu|cuda]
                       [--precision auto|fp32|bf16] [--compile] [--checkpoint PATH] [--fps F] [--workers N]
                       [--stereo MM]
    sim2real translate RUN --views VIEWS_DIR --out DIR [...]

Writes DIR/frames/000000.png ..., DIR/video.mp4, DIR/ground_truth/ and DIR/translate.json
(docs/formats.md, "Translate output"); with --stereo also DIR/right/ (the right eye's frames,
video and ground truth) and DIR/stereo/ (disparity).
"""

from __future__ import annotations

import argparse
import sys

from sim2real.cli.args import EMULATED_BF16, add_compile_arg, add_precision_arg, positive_float, positive_int
from sim2real.errors import UserError


def register(sub) -> None:
    p = sub.add_parser("translate", help="translate a trajectory or views folder into video + ground truth")
    p.add_argument("run", metavar="RUN", help="training run folder (uses RUN/checkpoints/last.pt)")
    p.add_argument("--scene", metavar="SCENE", help="scene folder (or the name of a scene the run was trained on)")
    p.add_argument("--trajectory", metavar="FILE", help="trajectory file (sim2real scene trajectory / TUM rows)")
    p.add_argument("--views", metavar="VIEWS_DIR", help="a views folder (sim2real render) instead of --scene/--trajectory")
    p.add_argument("--out", required=True, metavar="DIR", help="new or empty output folder")
    p.add_argument("--batch", type=positive_int,
                   help="frames per network call (default 8 on CUDA, 2 on a CPU, where it runs faster)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    add_precision_arg(p)
    add_compile_arg(p)
    p.add_argument("--checkpoint", metavar="PATH", help="checkpoint file instead of RUN/checkpoints/last.pt")
    p.add_argument("--fps", type=positive_float, help="video frame rate (default: the trajectory's, else 5)")
    p.add_argument("--workers", type=positive_int,
                   help="ray-casting processes (default: 1 for short or small trajectories, else one per core)")
    p.add_argument("--stereo", type=positive_float, metavar="MM",
                   help="also translate a right eye MM millimetres to the right of every camera (a rectified "
                        "stereo pair, as a stereo laparoscope's; about 4-5 mm) with its disparity")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.engine.precision import emulated_bf16
    from sim2real.inference.model import load_run
    from sim2real.inference.translate import trajectory_source, translate_sequence, views_source

    if args.views and (args.scene or args.trajectory):
        raise UserError("give either --views VIEWS_DIR or --scene SCENE --trajectory FILE, not both")
    if not args.views and not (args.scene and args.trajectory):
        raise UserError("give --scene SCENE and --trajectory FILE (or --views VIEWS_DIR)")
    if args.views and args.stereo:
        raise UserError("--stereo needs --scene SCENE --trajectory FILE: a views folder has one camera per view")
    model = load_run(args.run, args.device, args.checkpoint, args.precision, compile=args.compile)
    if emulated_bf16(model.device, model.amp):
        print(EMULATED_BF16, file=sys.stderr)
    source = (views_source(model, args.views) if args.views
              else trajectory_source(model, args.scene, args.trajectory, args.stereo))
    m = translate_sequence(model, source, args.out, batch=args.batch, fps=args.fps, workers=args.workers,
                           progress=not args.no_progress)
    print(f"{m['frames']} frames of '{m['scene']}' ({m['width']}x{m['height']}, {m['fps']:g} fps) written to {args.out}: "
          f"frames/, video.mp4, ground_truth/" + (", right/, stereo/" if m["stereo"] else ""))
    return 0
