"""Random camera poses (training views) and smooth trajectories (test sequences).

Random poses follow the paper's data: the camera centre lies in the scene's camera region and
outside every organ, it looks at a point of the liver's anterior side (the scene's
``anterior``) that it can see, and the scene's ``up`` (towards the patient's head) points up
in the image. A pose whose view shows more than :data:`MAX_BACKGROUND` background (rays that
escape through a hole of an open mesh) is drawn again; ``caster.skipped_background`` counts
those.

Trajectories pass a cubic spline through a few random look-from / look-at keys, so the camera
pans across the scene with varying distance (paper: 100 frames, 20 s at 5 fps).

Trajectory files use the TUM RGB-D pose format, one row per frame, camera to world::

    # sim2real trajectory v1
    # width 512
    # height 256
    # K fx 0 cx 0 fy cy 0 0 1
    # fps 5
    timestamp tx ty tz qx qy qz qw
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from scipy.interpolate import CubicSpline

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, atomic_write_text, read_json_or_none
from sim2real.render.motion import measure, pair_flow_px, rotation_deg
from sim2real.scene.camera import (Camera, intrinsics_from_fov, intrinsics_from_values, invert_rigid, look_at,
                                   rotation_to_quaternion)
from sim2real.scene.conventions import DEFAULT_FLOW_BUDGET, DEFAULT_MAX_DEG_PER_FRAME, LOOKS
from sim2real.scene.tum import read_tum

MAX_BACKGROUND = 0.3
"""Largest share of background pixels of a random training view (estimated on a coarse grid of
rays, :meth:`~sim2real.render.raycast.RayCaster.background_share`)."""


def _liver_targets(caster) -> tuple[np.ndarray, int]:
    scene = caster.scene
    ids = scene.objects_of("liver") or list(range(len(scene.objects)))
    k = ids[0]
    mesh = scene.objects[k].mesh
    v = np.asarray(mesh.vertices)
    front = np.asarray(mesh.vertex_normals) @ scene.anterior > 0.2  # the anterior side
    return (v[front] if front.any() else v), k


def sample_poses(caster, n: int, height: int, width: int, fov_x_deg: float | None, seed: int, max_tries: int = 200,
                 max_background: float = MAX_BACKGROUND, K: np.ndarray | None = None) -> list[Camera]:
    """``n`` random training views of ``caster.scene`` (see module docstring). ``K``: the
    cameras' intrinsics instead of ``fov_x_deg``'s (as in :func:`make_trajectory`)."""
    return list(iter_poses(caster, n, height, width, fov_x_deg, seed, max_tries, max_background, K))


def iter_poses(caster, n: int, height: int, width: int, fov_x_deg: float | None, seed: int,
               max_tries: int = 200, max_background: float = MAX_BACKGROUND,
               K: np.ndarray | None = None) -> Iterator[Camera]:
    """The cameras of :func:`sample_poses`, one at a time (a renderer draws them as it goes).
    The arguments are checked now, not at the first camera."""
    if n < 1:
        raise UserError(f"the number of views must be at least 1, got {n}")
    K = _intrinsics(width, height, fov_x_deg, K)
    return _poses(caster, n, K, height, width, np.random.default_rng(seed), max_tries, max_background)


def _poses(caster, n: int, K: np.ndarray, height: int, width: int, rng: np.random.Generator,
           max_tries: int, max_background: float = MAX_BACKGROUND) -> Iterator[Camera]:
    scene = caster.scene
    targets, liver = _liver_targets(caster)
    for _ in range(n):
        for _try in range(max_tries):
            eye = scene.camera_region.sample(rng, 1)[0]
            if not caster.free_space(eye[None])[0]:
                continue
            cand = targets[rng.integers(0, len(targets), size=16)]
            dist = np.linalg.norm(cand - eye, axis=1)
            ok = caster.visible(eye, cand, liver) & (dist > 20.0)
            if not ok.any():
                continue
            target = cand[np.nonzero(ok)[0][0]]
            cam = Camera(K, look_at(eye, target, scene.up), height, width)
            # closed scenes (no ray escapes) draw exactly the poses they drew before this check
            if max_background < 1.0 and caster.background_share(cam) > max_background:
                caster.skipped_background += 1
                continue
            yield cam
            break
        else:
            raise UserError(f"could not place a camera in scene '{scene.name}' that sees the liver with at most "
                            f"{max_background:.0%} background; check its camera region")


def _intrinsics(width: int, height: int, fov_x_deg: float | None, K: np.ndarray | None) -> np.ndarray:
    """``K`` where given (checked against the image size), else the K of ``fov_x_deg``."""
    if K is None:
        return intrinsics_from_fov(width, height, fov_x_deg)
    K = np.asarray(K, np.float64)
    return intrinsics_from_values(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2])


def linear_path(caster, frames: int, height: int, width: int, fov_x_deg: float, step_mm: float,
                rng: np.random.Generator, max_tries: int = 200, K: np.ndarray | None = None) -> list[Camera]:
    """A short random linear camera path (ReCycle's and OF-UNIT's training triplets, paper
    supplementary): a random training pose (:func:`sample_poses`' rules) whose eye and look-at
    point both move ``step_mm`` per frame along one random direction, so the view pans without
    turning. Every eye stays in free space; the path is redrawn otherwise."""
    scene = caster.scene
    K = _intrinsics(width, height, fov_x_deg, K)
    for _ in range(max_tries):
        first = next(_poses(caster, 1, K, height, width, rng, max_tries))
        c2w = first.camera_to_world
        eye, forward = c2w[:3, 3], c2w[:3, 2]
        target = eye + forward * 50.0
        d = rng.normal(size=3)
        d /= max(np.linalg.norm(d), 1e-12)
        eyes = eye + np.arange(frames)[:, None] * step_mm * d
        if not caster.free_space(eyes).all():
            continue
        return [Camera(K, look_at(e, target + (e - eye), scene.up), height, width) for e in eyes]
    raise UserError(f"could not place a linear camera path of {frames} frames in scene '{scene.name}'; "
                    "check its camera region")


@dataclass
class Trajectory:
    """Per-frame cameras of a sequence plus its frame rate."""

    cameras: list[Camera]
    fps: float = 5.0
    motion: dict | None = None
    """Measured motion (:func:`measure_motion`) and the budget it was made with; saved in the
    JSON side file ``PATH.json`` beside the pose file."""

    def save(self, path: str | os.PathLike) -> None:
        c0 = self.cameras[0]
        lines = [
            "# sim2real trajectory v1",
            f"# width {c0.width}",
            f"# height {c0.height}",
            "# K " + " ".join(f"{x:.10g}" for x in c0.K.reshape(-1)),
            f"# fps {self.fps:g}",
            "# timestamp tx ty tz qx qy qz qw   (camera to world, mm)",
        ]
        for i, cam in enumerate(self.cameras):
            c2w = cam.camera_to_world
            q = rotation_to_quaternion(c2w[:3, :3])
            row = [i / self.fps, *c2w[:3, 3], *q]
            lines.append(" ".join(f"{x:.9f}" for x in row))
        atomic_write_text(path, "\n".join(lines) + "\n")
        if self.motion is not None:

            atomic_write_json(side_file(path), {"format": "sim2real-trajectory-motion/1", "frames": len(self.cameras),
                                                "fps": self.fps, "motion": self.motion})

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Trajectory":
        comments, poses = read_tum(path, "trajectory")
        header: dict[str, list[float]] = {}
        for lineno, line in comments:
            parts = line[1:].split()
            if parts and parts[0] in ("width", "height", "K", "fps"):
                try:
                    header[parts[0]] = [float(x) for x in parts[1:]]
                except ValueError:
                    raise UserError(f"{path}:{lineno}: bad header line '{line}'") from None
        for key, n in (("width", 1), ("height", 1), ("K", 9)):
            if key not in header or len(header[key]) != n:
                raise UserError(f"{path}: header line '# {key}' is missing or malformed")
        if not poses:
            raise UserError(f"{path}: trajectory has no poses")
        width, height = int(header["width"][0]), int(header["height"][0])
        K = np.array(header["K"]).reshape(3, 3)
        cams = [Camera(K, invert_rigid(c2w), height, width) for _, c2w in poses]
        fps = header.get("fps", [5.0])[0]
        # A side file that is missing, unreadable or does not describe these poses is not used.
        data = read_json_or_none(side_file(path))
        motion = data.get("motion") if data is not None and data.get("frames") == len(cams) else None
        return cls(cams, fps=fps if fps > 0 else 5.0, motion=motion)


def side_file(path: str | os.PathLike) -> Path:
    """The JSON side file of a trajectory file: ``traj.txt`` -> ``traj.txt.json``."""
    p = Path(path)
    return p.with_name(p.name + ".json")


_MEASURE_WIDTH = 128  # the path is timed on G-buffers of this width (flow fractions do not depend on it)


def make_trajectory(
    caster, frames: int = 100, height: int = 256, width: int = 512, fov_x_deg: float = 75.0,
    seed: int = 0, keys: int = 5, fps: float = 5.0, max_tries: int = 50,
    flow_budget: float | None = DEFAULT_FLOW_BUDGET, max_deg_per_frame: float | None = DEFAULT_MAX_DEG_PER_FRAME,
    look: str = "smooth", K: np.ndarray | None = None,
) -> Trajectory:
    """A smooth camera path that pans across the liver with varying distance.

    The eye passes a cubic spline through ``keys`` random points of the camera region, sorted
    along its longest axis. ``look="smooth"`` (default) aims it at a look-at point that moves
    smoothly and monotonically over the liver (a quadratic fit through the liver points below
    the eye keys); ``look="swing"`` aims at a new random liver point at every key (the paths
    before the motion budget: 16 px/frame at 512 px, a stress test).

    ``flow_budget`` (fraction of the width) and ``max_deg_per_frame`` then time the path: it is
    re-parametrised so that every frame step moves the image by the same amount, measured by ray
    casting the path (:mod:`sim2real.render.motion`), at most ``flow_budget`` of the width in
    median flow and ``max_deg_per_frame`` in rotation. A path longer than the budget allows is cut
    to its middle part; a shorter one runs slower. ``None`` for both: the spline is sampled
    uniformly (the old behaviour). The result carries its measured motion (``Trajectory.motion``).
    ``K``: the cameras' intrinsics (e.g. a calibrated endoscope's,
    :func:`~sim2real.scene.camera.intrinsics_from_values`) instead of ``fov_x_deg``'s.
    """
    if frames < 2:
        raise UserError(f"a trajectory needs at least 2 frames, got {frames}")
    if look not in LOOKS:
        raise UserError(f"look must be one of {', '.join(LOOKS)}, got '{look}'")
    for name, v in (("flow budget", flow_budget), ("max degrees per frame", max_deg_per_frame)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise UserError(f"the {name} must be positive, got {v}")
    scene = caster.scene
    K = _intrinsics(width, height, fov_x_deg, K)
    rng = np.random.default_rng(seed)
    targets, liver = _liver_targets(caster)
    for _ in range(max_tries):
        eyes = scene.camera_region.sample(rng, keys)
        # Sweep: order the keys along the region's longest axis so the camera pans across.
        axis = int(np.argmax(scene.camera_region.radii))
        eyes = eyes[np.argsort(eyes[:, axis])]
        looks = []
        for eye in eyes:
            cand = targets[rng.integers(0, len(targets), size=32)]
            if look == "smooth":  # the candidates nearest to the point below the eye first
                below = np.linalg.norm(np.cross(cand - eye, scene.up), axis=1)
                cand = cand[np.argsort(below)]
            ok = caster.visible(eye, cand, liver)
            looks.append(cand[np.nonzero(ok)[0][0]] if ok.any() else None)
        if any(l is None for l in looks) or not caster.free_space(eyes).all():
            continue
        s = np.linspace(0.0, 1.0, keys)
        eye_fn = CubicSpline(s, eyes, bc_type="natural")
        if look == "smooth":
            coef = np.polynomial.polynomial.polyfit(s, np.array(looks), 2)
            look_fn = lambda u, c=coef: np.polynomial.polynomial.polyval(np.asarray(u), c).T  # noqa: E731
        else:
            look_fn = CubicSpline(s, np.array(looks), bc_type="natural")
        if flow_budget is None and max_deg_per_frame is None:
            u = np.linspace(0.0, 1.0, frames)
        else:
            u = _timed_parameters(caster, eye_fn, look_fn, frames, K, height, width, flow_budget, max_deg_per_frame)
        path_eye = scene.camera_region.clamp(eye_fn(u))
        path_look = look_fn(u)
        if not caster.free_space(path_eye).all():
            continue
        if np.min(np.linalg.norm(path_look - path_eye, axis=1)) < 15.0:
            continue
        cams = [Camera(K, look_at(e, l, scene.up), height, width) for e, l in zip(path_eye, path_look)]
        traj = Trajectory(cams, fps=fps)
        traj.motion = measure_motion(caster, cams)
        traj.motion.update(budget={"flow_frac_per_frame": flow_budget, "max_deg_per_frame": max_deg_per_frame,
                                   "look": look, "seed": int(seed)})
        return traj
    raise UserError(f"could not find a collision-free trajectory in scene '{scene.name}'; check its camera region")


def _measure_cameras(cams: list[Camera]) -> list[Camera]:
    """The same cameras at a width of about :data:`_MEASURE_WIDTH` px (flow fractions are unchanged)."""
    c0 = cams[0]
    s = min(1.0, _MEASURE_WIDTH / c0.width)
    h, w = max(8, round(c0.height * s)), max(8, round(c0.width * s))
    K = c0.K.copy()
    K[0] *= w / c0.width
    K[1] *= h / c0.height
    return [Camera(K, c.world_to_camera, h, w) for c in cams]


def measure_motion(caster, cameras: list[Camera]) -> dict:
    """:func:`sim2real.render.motion.measure` of a path, ray cast at about 128 px width; pixel
    figures are given at the cameras' own width."""
    small = _measure_cameras(cameras)
    m = measure(caster.render(c) for c in small)
    scale = cameras[0].width / small[0].width
    m.update(width=cameras[0].width, measured_at_width=small[0].width,
             flow_px_per_frame_median=m["flow_px_per_frame_median"] * scale,
             flow_px_per_frame=[round(x * scale, 3) for x in m["flow_px_per_frame"]])
    return m


def _timed_parameters(caster, eye_fn, look_fn, frames: int, K, height: int, width: int,
                      flow_budget: float | None, max_deg: float | None, oversample: int = 4) -> np.ndarray:
    """Spline parameters of ``frames`` frames whose steps all move the same amount, at most
    one budget unit (the larger of flow / flow_budget and rotation / max_deg)."""
    n = max(oversample * frames, 64)
    u = np.linspace(0.0, 1.0, n)
    eye = caster.scene.camera_region.clamp(eye_fn(u))
    lk = look_fn(u)
    cams = _measure_cameras([Camera(K, look_at(e, l, caster.scene.up), height, width) for e, l in zip(eye, lk)])
    gbs = [caster.render(c) for c in cams]
    step = np.zeros(n - 1)
    for i in range(n - 1):
        cost = 0.0
        if flow_budget is not None:
            cost = max(cost, pair_flow_px(gbs[i], gbs[i + 1])[0] / cams[0].width / flow_budget)
        if max_deg is not None:
            cost = max(cost, rotation_deg(cams[i].world_to_camera, cams[i + 1].world_to_camera) / max_deg)
        step[i] = cost
    cum = np.concatenate([[0.0], np.cumsum(step)])
    need = float(frames - 1)
    total = cum[-1]
    if total <= need:  # the whole path, slower than the budget
        targets = np.linspace(0.0, total, frames)
    else:  # the middle part of the path at the budget
        a = 0.5 * (total - need)
        targets = np.linspace(a, a + need, frames)
    # Cumulative motion is non-decreasing; interpolate the inverse (ties: np.interp takes the first).
    return np.interp(targets, cum, u)


