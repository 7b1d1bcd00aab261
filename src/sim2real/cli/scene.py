"""``sim2real scene``: generate procedural scenes, import meshes, check scenes, make trajectories."""

from __future__ import annotations

import argparse

from sim2real.cli.args import add_motion_args, motion_kwargs, non_negative_int, positive_float, positive_int
from sim2real.errors import UserError


def register(sub) -> None:
    p = sub.add_parser("scene", help="create, import and check scenes; make camera trajectories")
    ss = p.add_subparsers(dest="scene_command", required=True, parser_class=type(p))

    g = ss.add_parser("generate", help="build a procedural abdominal scene")
    g.add_argument("--seed", type=non_negative_int, required=True)
    g.add_argument("--out", required=True, help="new scene directory")
    g.add_argument("--name", default=None)
    g.set_defaults(func=_generate)

    i = ss.add_parser("import", help="make a scene from your own meshes (OBJ, PLY, STL, glTF/GLB, ...)")
    i.add_argument("--mesh", action="append", required=True, metavar="PATH[=CLASS]",
                   help="a mesh file and its class; without =CLASS every part of the file is an object "
                        "whose class comes from --class or from its name")
    i.add_argument("--class", dest="classes", action="append", default=[], metavar="PART=CLASS",
                   help="class of a named part of a multi-object file")
    i.add_argument("--camera-region", required=True, metavar="CX,CY,CZ,RX,RY,RZ",
                   help="ellipsoid (mm) where cameras may be: centre and radii")
    i.add_argument("--up", default="0,1,0", metavar="X,Y,Z", help="world direction towards the patient's head")
    i.add_argument("--name", default=None)
    i.add_argument("--out", required=True)
    i.set_defaults(func=_import)

    c = ss.add_parser("check", help="load a scene and validate its meshes and camera region")
    c.add_argument("scene")
    c.set_defaults(func=_check)

    t = ss.add_parser("trajectory", help="a smooth camera path through a scene (TUM pose rows)")
    t.add_argument("scene")
    t.add_argument("--frames", type=positive_int, default=100)
    t.add_argument("--height", type=positive_int, default=256)
    t.add_argument("--width", type=positive_int, default=512)
    t.add_argument("--fov", type=positive_float, default=75.0, help="horizontal field of view, degrees")
    t.add_argument("--fps", type=positive_float, default=5.0)
    t.add_argument("--seed", type=non_negative_int, default=0)
    add_motion_args(t)
    t.add_argument("--out", required=True, help="trajectory file to write (and its motion in OUT.json)")
    t.set_defaults(func=_trajectory)


def _generate(args: argparse.Namespace) -> int:
    from sim2real.scene.procedural import generate_scene

    scene = generate_scene(args.seed, args.name)
    scene.save(args.out)
    print(f"scene '{scene.name}' ({len(scene.objects)} objects) written to {args.out}")
    return 0


def _import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from sim2real.render.raycast import check_camera_region
    from sim2real.scene.io import class_from_name, load_mesh, load_parts, parse_vector
    from sim2real.scene.scene import CameraRegion, Scene, SceneObject

    mapping = {}
    for item in args.classes:
        if "=" not in item:
            raise UserError(f"--class expects PART=CLASS, got '{item}'")
        part, cls = item.split("=", 1)
        mapping[part] = cls
    objects = []
    for spec in args.mesh:
        path, _, cls = spec.partition("=")
        if cls:
            objects.append(SceneObject(Path(path).stem, cls, load_mesh(path, Path(path).stem)))
        else:
            for part, mesh in load_parts(path).items():
                objects.append(SceneObject(part, class_from_name(part, mapping), mesh))
    region = parse_vector(args.camera_region, 6, "--camera-region")
    scene = Scene(
        name=args.name or Path(args.out).name,
        objects=objects,
        camera_region=CameraRegion(region[:3], region[3:]),
        up=parse_vector(args.up, 3, "--up"),
    )
    check_camera_region(scene)
    scene.save(args.out)
    print(f"scene '{scene.name}' ({len(objects)} objects: {', '.join(scene.classes)}) written to {args.out}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from sim2real.render.raycast import check_camera_region
    from sim2real.scene.scene import Scene

    scene = Scene.load(args.scene)
    check_camera_region(scene)
    for o in scene.objects:
        print(f"{o.name:20s} {o.cls:15s} {len(o.mesh.faces):8d} triangles  watertight={o.mesh.is_watertight}")
    print(f"scene '{scene.name}' is valid")
    return 0


def _trajectory(args: argparse.Namespace) -> int:
    from sim2real.render.raycast import RayCaster, check_camera_region
    from sim2real.scene.camera import check_size
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    check_size(args.height, args.width)
    scene = Scene.load(args.scene)
    caster = RayCaster(scene)
    check_camera_region(scene, caster)
    traj = make_trajectory(caster, args.frames, args.height, args.width, args.fov, seed=args.seed, fps=args.fps,
                           **motion_kwargs(args))
    traj.save(args.out)
    m = traj.motion
    print(f"{len(traj.cameras)} poses written to {args.out} (median flow {m['flow_px_per_frame_median']:.2f} px/frame, "
          f"max rotation {m['deg_per_frame_max']:.2f} deg/frame, overlap after 10 frames {m['overlap']['10']:.0%}; "
          f"{args.out}.json)")
    return 0
