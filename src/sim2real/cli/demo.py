"""``sim2real demo``: the whole path on data it makes itself (embedded defaults)."""

from __future__ import annotations

import argparse

from sim2real.cli.args import non_negative_int, positive_int


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the pipeline end to end on procedural data it makes itself")
    p.add_argument("--out", required=True, help="new output directory")
    p.add_argument("--scenes", type=positive_int, default=2, help="procedural simulated scenes")
    p.add_argument("--views", type=positive_int, default=8, help="random views per scene")
    p.add_argument("--frames", type=positive_int, default=100, help="frames of the test trajectory")
    p.add_argument("--height", type=positive_int, default=256)
    p.add_argument("--width", type=positive_int, default=512)
    p.add_argument("--seed", type=non_negative_int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sim2real.data.views import write_views_manifest
    from sim2real.fileio import prepare_output_dir
    from sim2real.render.raycast import RayCaster, render_views
    from sim2real.scene.camera import check_size
    from sim2real.scene.procedural import generate_scene
    from sim2real.scene.trajectory import make_trajectory, sample_poses

    check_size(args.height, args.width)
    out = prepare_output_dir(args.out)
    for k in range(args.scenes):
        scene = generate_scene(args.seed + k)
        scene_dir = scene.save(out / "scenes" / scene.name)
        caster = RayCaster(scene)
        cams = sample_poses(caster, args.views, args.height, args.width, 75.0, seed=args.seed + k)
        views = out / "views" / scene.name
        render_views(scene_dir, cams, [views / f"view_{i:05d}.npz" for i in range(len(cams))], preview=True)
        write_views_manifest(views, scene.name, scene_dir, len(cams))
        if k == 0:
            traj = make_trajectory(caster, args.frames, args.height, args.width, seed=args.seed)
            traj.save(out / "trajectory.txt")
            seq = out / "sequence" / scene.name
            render_views(scene_dir, traj.cameras, [seq / f"view_{i:05d}.npz" for i in range(len(traj.cameras))], preview=True)
            write_views_manifest(seq, scene.name, scene_dir, len(traj.cameras))
    print(f"demo written to {out}: scenes/, views/ (random views with a_ref previews), trajectory.txt, sequence/")
    return 0
