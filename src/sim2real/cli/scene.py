"""``sim2real scene``: generate procedural scenes, import meshes, check and preview scenes, make
trajectories."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sim2real.cli.args import add_camera_args, add_motion_args, camera_matrix, counted, motion_kwargs, non_negative_int, positive_float, positive_int
from sim2real.errors import UserError
from sim2real.scene.conventions import CAMERA_AXES, DEFAULT_CREASE_DEG, DEFAULT_FLOW_BUDGET, DEFAULT_MAX_DEG_PER_FRAME, UNITS


def register(sub) -> None:
    p = sub.add_parser("scene", help="create, import and check scenes; make camera trajectories")
    ss = p.add_subparsers(dest="scene_command", required=True, parser_class=type(p))

    g = ss.add_parser("generate", help="build a procedural abdominal scene")
    g.add_argument("--seed", type=non_negative_int, required=True)
    g.add_argument("--out", required=True, help="new scene directory")
    g.add_argument("--name", default=None)
    g.set_defaults(func=_generate)

    i = ss.add_parser("import", help="make a scene from your own meshes (OBJ, PLY, STL, glTF/GLB, ...)")
    i.add_argument("--mesh", action="extend", nargs="+", required=True, metavar="PATH[=CLASS]",
                   help="mesh files or folders of them, each with its class or not (repeatable; 'organs/*.stl' "
                        "and 'organs/' work); "
                        "without =CLASS every part of a file is an object whose class comes from --class "
                        "or from its name (e.g. 'Kidney_left' is a kidney)")
    i.add_argument("--class", dest="classes", action="append", default=[], metavar="PART=CLASS",
                   help="class of a named part of a multi-object file")
    i.add_argument("--class-table", default=None, metavar="FILE",
                   help="JSON class table: new classes and their a_ref/label/palette colours (docs/own-data.md)")
    i.add_argument("--units", choices=tuple(UNITS), default="mm",
                   help="unit of the mesh files (default mm); sizes are checked for plausibility")
    i.add_argument("--camera-region", required=True, metavar="auto|CX,CY,CZ,RX,RY,RZ",
                   help="ellipsoid (mm) where cameras may be: centre and radii, or 'auto' to fit one into the "
                        "cavity in front of the liver")
    i.add_argument("--up", default="0,1,0", metavar="X,Y,Z", help="world direction towards the patient's head")
    i.add_argument("--anterior", default="0,0,1", metavar="X,Y,Z", help="world direction towards the patient's front")
    i.add_argument("--crease-angle", type=positive_float, default=DEFAULT_CREASE_DEG, metavar="DEG",
                   help=f"smooth normals for STL/OBJ meshes without them keep edges sharper than this "
                        f"(default {DEFAULT_CREASE_DEG:g})")
    i.add_argument("--flat-normals", action="store_true",
                   help="keep the file's triangles as they are (no welding, no smooth normals)")
    i.add_argument("--name", default=None)
    i.add_argument("--out", required=True)
    i.set_defaults(func=_import)

    c = ss.add_parser("check", help="load a scene, validate its meshes and camera region, measure escaping rays")
    c.add_argument("scene")
    c.add_argument("--views", type=positive_int, default=32, help="random views whose background share is measured")
    c.set_defaults(func=_check)

    v = ss.add_parser("preview", help="a contact sheet of random views and a trajectory (a_ref), before training")
    v.add_argument("scene")
    v.add_argument("--out", required=True, help="PNG file to write")
    v.add_argument("--views", type=positive_int, default=8, help="random views on the sheet")
    v.add_argument("--frames", type=positive_int, default=8, help="frames of one test trajectory on the sheet")
    v.add_argument("--height", type=positive_int, default=128)
    v.add_argument("--width", type=positive_int, default=256)
    v.add_argument("--fov", type=positive_float, default=75.0)
    v.add_argument("--seed", type=non_negative_int, default=0)
    v.set_defaults(func=_preview)

    t = ss.add_parser("trajectory", help="a smooth camera path through a scene, or your own poses (TUM pose rows)")
    t.add_argument("scene")
    t.add_argument("--frames", type=positive_int, default=None, help="frames of a generated path (default 100)")
    t.add_argument("--height", type=positive_int, default=256)
    t.add_argument("--width", type=positive_int, default=512)
    add_camera_args(t)
    t.add_argument("--fps", type=positive_float, default=None,
                   help="frame rate (default 5; with --poses: resample them at this rate, default one frame per row)")
    t.add_argument("--seed", type=non_negative_int, default=None, help="seed of a generated path (default 0)")
    add_motion_args(t)
    t.add_argument("--poses", default=None, metavar="FILE",
                   help="your own camera path instead: TUM rows 'timestamp tx ty tz qx qy qz qw' (camera to world, "
                        "seconds) in the scene's world frame, e.g. a tracked endoscope's or a robot's; or a .blend "
                        "file, whose scene camera's animation is read over its frame range, with its lens")
    t.add_argument("--units", choices=tuple(UNITS), default="mm",
                   help="units of the --poses translations, as of the scene's meshes at import (default mm)")
    t.add_argument("--axes", choices=CAMERA_AXES, default=None,
                   help="camera axes of --poses rows: opencv (default; x right, y down, looking along +z: TUM's) or "
                        "opengl (y up, looking along -z: Blender's, OpenGL's)")
    t.add_argument("--camera", default=None, metavar="NAME", help="the camera object of a --poses .blend file "
                                                                  "(default: its scene camera)")
    t.add_argument("--out", required=True, help="trajectory file to write (and its motion in OUT.json)")
    t.set_defaults(func=_trajectory)


def _generate(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.scene.procedural import generate_scene

    scene = generate_scene(args.seed, args.name)
    scene.save(args.out)
    print(f"scene '{scene.name}' ({counted(len(scene.objects), 'object')}) written to {args.out}")
    return 0


def _import(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.scene.importer import import_scene

    scene = import_scene(args)
    r = scene.camera_region
    print(f"scene '{scene.name}' ({counted(len(scene.objects), 'object')}: {', '.join(scene.classes)}; "
          f"camera region centre "
          f"{', '.join(f'{x:.1f}' for x in r.center)} radii {', '.join(f'{x:.1f}' for x in r.radii)} mm) "
          f"written to {args.out}")
    return 0


def _check(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    import numpy as np

    from sim2real.render.raycast import RayCaster, check_camera_region
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import MAX_BACKGROUND, sample_poses

    scene = Scene.load(args.scene)
    caster = RayCaster(scene)
    check_camera_region(scene, caster)
    for o in scene.objects:
        print(f"{o.name:20s} {o.cls:15s} {len(o.mesh.faces):8d} triangles  watertight={o.mesh.is_watertight}")
    cams = sample_poses(caster, args.views, 128, 256, 75.0, seed=0, max_background=1.0)
    share = np.array([caster.background_share(c) for c in cams])
    print(f"background (escaping rays) per random view: median {np.median(share):.1%}, max {share.max():.1%}; "
          f"{int((share > MAX_BACKGROUND).sum())} of {len(share)} views above {MAX_BACKGROUND:.0%} "
          f"(such views are not used for training)")
    print(f"scene '{scene.name}' is valid")
    return 0


def _preview(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.scene.preview import contact_sheet

    path = contact_sheet(args.scene, args.out, args.views, args.frames, args.height, args.width, args.fov, args.seed)
    print(f"preview of {args.views} random views and {args.frames} trajectory frames written to {path}")
    return 0


def _trajectory(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.render.raycast import RayCaster, check_camera_region
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    K = camera_matrix(args)
    scene = Scene.load(args.scene)
    caster = RayCaster(scene)
    if args.poses is not None:
        traj, rows = _own_poses(args, K, scene, caster)
        source = f"from {counted(rows, 'pose row')} of {args.poses}"
    else:
        if args.units != "mm" or args.axes is not None or args.camera is not None:
            raise UserError("--units, --axes and --camera describe --poses: give them with --poses FILE")
        check_camera_region(scene, caster)
        traj = make_trajectory(caster, args.frames or 100, args.height, args.width, seed=args.seed or 0,
                               fps=args.fps or 5.0, K=K, **motion_kwargs(args))
        source = None
    traj.save(args.out)
    m = traj.motion
    # what was measured: a single frame has no flow, a path of 10 frames or fewer no overlap after 10
    gaps = [int(k) for k, v in m["overlap"].items() if v is not None]
    parts = [source] if source else []
    parts += [f"median flow {m['flow_px_per_frame_median']:.2f} px/frame"] if m["flow_px_per_frame_median"] is not None else []
    parts += [f"max rotation {m['deg_per_frame_max']:.2f} deg/frame"] if m["deg_per_frame_max"] is not None else []
    if gaps:
        k = max(gaps)
        parts.append(f"overlap after {k} frame{'s' if k > 1 else ''} {m['overlap'][str(k)]:.0%}")
    print(f"{len(traj.cameras)} poses written to {args.out} ({', '.join(parts + [f'{args.out}.json'])})")
    return 0


def _own_poses(args: argparse.Namespace, K, scene, caster):
    """The trajectory of ``--poses`` with its measured motion; its cameras checked against the
    scene: refused when most lie inside an organ or outside the abdominal wall (poses in another
    frame or unit), one line on stderr when some do or when most views see no surface."""
    import numpy as np

    from sim2real.scene.pose_import import trajectory_from_poses
    from sim2real.scene.trajectory import MAX_BACKGROUND, measure_motion

    generated = [f for f, v, d in (("--frames", args.frames, None), ("--seed", args.seed, None),
                                   ("--flow-budget", args.flow_budget, DEFAULT_FLOW_BUDGET),
                                   ("--max-deg-per-frame", args.max_deg_per_frame, DEFAULT_MAX_DEG_PER_FRAME),
                                   ("--look", args.look, "smooth")) if v != d]
    if generated:
        raise UserError(f"{generated[0]} shapes a generated path; with --poses the path is the file's")
    blend = Path(args.poses).suffix.lower() == ".blend"
    axes = "opengl" if blend else args.axes or "opencv"
    if blend:
        traj, rows = _blender_camera(args, K)
    else:
        if args.camera is not None:
            raise UserError("--camera names a camera of a .blend file; --poses rows are one camera's")
        traj, rows = trajectory_from_poses(args.poses, K, args.height, args.width, args.units, axes, args.fps,
                                           note=lambda m: print(f"sim2real: note: {m}", file=sys.stderr))
    centres = np.stack([c.camera_to_world[:3, 3] for c in traj.cameras])
    organ = caster.containing_object(centres)
    outside = ~caster.enclosed(centres) if scene.objects_of("abdominal_wall") else np.zeros(len(centres), bool)
    stray = (organ >= 0) | outside
    hint = f"are the poses in the scene's frame, in --units {args.units}{'' if blend else f' with --axes {axes}'}?"
    if stray.mean() > 0.5:
        k = int(np.argmax(stray))
        where = f"inside organ '{scene.objects[organ[k]].name}'" if organ[k] >= 0 else "outside the abdominal wall"
        raise UserError(f"{_stray(stray)} inside an organ or outside the abdominal wall (frame {k}: {where}): {hint}")
    if stray.any():
        print(f"sim2real: note: {_stray(stray)} inside an organ or outside the abdominal wall "
              f"(first: frame {int(np.argmax(stray))})", file=sys.stderr)
    background = float(np.median([caster.background_share(c) for c in traj.cameras]))
    if background > MAX_BACKGROUND:
        print(f"sim2real: note: the median view sees no surface in {background:.0%} of its pixels: {hint}",
              file=sys.stderr)
    traj.motion = measure_motion(caster, traj.cameras)
    traj.motion["source"] = {"poses": str(args.poses), "rows": rows, "units": args.units, "axes": axes,
                             "resampled_fps": args.fps}
    return traj, rows


def _blender_camera(args: argparse.Namespace, K):
    """The trajectory of a .blend file's camera: its path in Blender's camera axes and, unless
    --fov or --intrinsics is given, its lens."""
    import tempfile

    from sim2real.scene.blend import blend_camera_path
    from sim2real.scene.pose_import import blender_intrinsics, trajectory_from_poses

    if args.axes is not None:
        raise UserError("a .blend file's camera has Blender's axes: drop --axes")
    if not Path(args.poses).is_file():
        raise UserError(f"pose file {args.poses} does not exist")
    with tempfile.TemporaryDirectory(prefix="sim2real-blend-") as tmp:
        rows = Path(tmp) / "camera.txt"
        blend_camera_path(args.poses, rows, args.camera)
        if args.fov is None and args.intrinsics is None:
            K, note = blender_intrinsics(rows, args.width, args.height)
            if note:
                print(f"sim2real: note: {note}", file=sys.stderr)
        return trajectory_from_poses(rows, K, args.height, args.width, args.units, "opengl", args.fps)


def _stray(stray) -> str:
    n = int(stray.sum())
    return f"{n} of {len(stray)} cameras {'lies' if n == 1 else 'lie'}"
