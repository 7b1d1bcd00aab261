"""``sim2real render``: ray-cast views of a scene into G-buffer files (view_00000.npz, ...)."""

from __future__ import annotations

import argparse
import itertools

from sim2real.cli.args import add_camera_args, camera_matrix, counted, non_negative_float, non_negative_int, positive_int


def register(sub) -> None:
    p = sub.add_parser("render", help="ray-cast random views or a trajectory into G-buffers")
    p.add_argument("scene", help="scene directory")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--views", type=positive_int, help="number of random views")
    src.add_argument("--trajectory", help="trajectory file (one pose per frame)")
    p.add_argument("--height", type=positive_int, default=256)
    p.add_argument("--width", type=positive_int, default=512)
    add_camera_args(p)  # of the random views (a trajectory file holds its cameras)
    p.add_argument("--seed", type=non_negative_int, default=0)
    p.add_argument("--workers", type=positive_int, default=None, help="processes (default: all cores)")
    p.add_argument("--preview", action="store_true", help="also write the reference rendering a_ref as PNG")
    p.add_argument("--max-background", type=non_negative_float, default=None, metavar="SHARE",
                   help="random views with a larger share of background (escaping rays) are drawn again "
                        "(default 0.3; 1 keeps every view)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    import numpy as np

    from sim2real.data.views import write_views_manifest
    from sim2real.fileio import check_free_space, staged_output_dir
    from sim2real.render.raycast import RayCaster, check_camera_region, render_views
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import MAX_BACKGROUND, Trajectory, iter_poses

    scene = Scene.load(args.scene)
    caster = None
    max_bg = MAX_BACKGROUND if args.max_background is None else min(args.max_background, 1.0)
    if args.trajectory:
        cameras = Trajectory.load(args.trajectory).cameras
        count = len(cameras)
        caster = RayCaster(scene)
    else:
        K = camera_matrix(args)
        caster = RayCaster(scene)
        check_camera_region(scene, caster)
        # Poses are drawn while the workers render (about 2 ms each: 6 s before the first view
        # of 3,000 otherwise); the first one now, so that a scene without any fails before
        # anything is written.
        poses = iter_poses(caster, args.views, args.height, args.width, None, args.seed, max_background=max_bg, K=K)
        first = next(poses)
        cameras, count = itertools.chain([first], poses), args.views
    probe = caster.render(cameras[0] if args.trajectory else first)  # what a view file holds
    check_free_space(args.out, count * probe.nbytes, f"rendering {counted(count, 'view')} at "
                     f"{probe.width}x{probe.height}", "free space, write elsewhere or render fewer views")
    with staged_output_dir(args.out) as out:
        paths = [out / f"view_{i:05d}.npz" for i in range(count)]
        render_views(scene, cameras, paths, workers=args.workers, preview=args.preview, caster=caster)
        write_views_manifest(out, scene.name, args.scene, count)
    if args.trajectory:
        share = np.array([caster.background_share(c) for c in cameras])
        print(f"background (escaping rays) per view: median {np.median(share):.1%}, max {share.max():.1%}; "
              f"{int((share > max_bg).sum())} of {count} views above {max_bg:.0%}")
    elif caster.skipped_background:
        print(f"{caster.skipped_background} random views skipped: more than {max_bg:.0%} background (escaping rays)")
    print(f"{counted(count, 'view')} of '{scene.name}' written to {args.out}")
    return 0
