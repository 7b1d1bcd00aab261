"""``sim2real realdomain``: render the procedural stand-in for real laparoscopic video, with labels.

    sim2real realdomain --scenes DIR [DIR ...] --images N --out DIR
                        [--sequences K --frames F] [--seed S] [--height H --width W --fov DEG]
                        [--mask] [--blur PX] [--noise SIGMA] [--workers W]

Writes ``images/*.png`` and ``labels/*.png`` (class index per pixel, 255 = background),
``sequences/NNN/{images,labels,trajectory.txt}`` and ``manifest.json`` (docs/realdomain.md).
Use scenes made with other seeds than the simulated domain's: the domains are unpaired.
"""

from __future__ import annotations

import argparse

from sim2real.cli.args import non_negative_float, non_negative_int, positive_float, positive_int


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got '{text}'") from None


def register(sub) -> None:
    p = sub.add_parser(
        "realdomain",
        help="render stand-in 'real' laparoscopic frames with labels (the embedded target domain)",
        description=__doc__.replace("``", ""),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--scenes", nargs="+", required=True, metavar="DIR", help="scene directories (scene.json)")
    p.add_argument("--images", type=_int, required=True, metavar="N", help="random views, spread over the scenes")
    p.add_argument("--out", required=True, help="new (or empty) output directory")
    p.add_argument("--sequences", type=_int, default=0, metavar="K", help="smooth camera paths (default 0)")
    p.add_argument("--frames", type=_int, default=100, metavar="F", help="frames per sequence (default 100)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="master seed (default 0)")
    p.add_argument("--height", type=positive_int, default=256)
    p.add_argument("--width", type=positive_int, default=512)
    p.add_argument("--fov", type=positive_float, default=75.0, help="horizontal field of view, degrees")
    p.add_argument("--mask", action="store_true", help="black out the corners outside the endoscope's circle")
    p.add_argument("--blur", type=non_negative_float, default=0.6, help="Gaussian blur sigma in pixels (0 = none)")
    p.add_argument("--noise", type=non_negative_float, default=0.012, help="sensor noise sigma (0 = none)")
    p.add_argument("--workers", type=positive_int, default=None, help="processes (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.realdomain import RenderOptions
    from sim2real.realdomain.writer import make_real_domain

    options = RenderOptions(mask=args.mask, blur_px=args.blur, noise=args.noise)
    manifest = make_real_domain(
        args.scenes, args.out, images=args.images, sequences=args.sequences, frames=args.frames,
        seed=args.seed, height=args.height, width=args.width, fov_x_deg=args.fov, options=options,
        workers=args.workers, progress=not args.quiet,
    )
    n_seq = sum(len(s["frames"]) for s in manifest["sequence_list"])
    print(f"{manifest['images']} images and {len(manifest['sequence_list'])} sequences ({n_seq} frames) "
          f"written to {args.out}")
    return 0
