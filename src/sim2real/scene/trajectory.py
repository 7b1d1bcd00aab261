"""Random camera poses (training views) and smooth trajectories (test sequences).

Random poses follow the paper's data: the camera centre lies in the scene's camera region and
outside every organ, it looks at a point of the liver that it can see, and the scene's ``up``
(towards the patient's head) points up in the image.

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
from typing import Iterator

import numpy as np

from sim2real.errors import UserError
from sim2real.fileio import atomic_write_text
from sim2real.scene.camera import Camera, intrinsics_from_fov, invert_rigid, look_at, rotation_to_quaternion
from sim2real.scene.tum import read_tum


def _liver_targets(caster) -> tuple[np.ndarray, int]:
    scene = caster.scene
    ids = scene.objects_of("liver") or list(range(len(scene.objects)))
    k = ids[0]
    mesh = scene.objects[k].mesh
    v = np.asarray(mesh.vertices)
    up_facing = np.asarray(mesh.vertex_normals)[:, 2] > 0.2  # the anterior side
    return (v[up_facing] if up_facing.any() else v), k


def sample_poses(caster, n: int, height: int, width: int, fov_x_deg: float, seed: int, max_tries: int = 200) -> list[Camera]:
    """``n`` random training views of ``caster.scene`` (see module docstring)."""
    return list(iter_poses(caster, n, height, width, fov_x_deg, seed, max_tries))


def iter_poses(caster, n: int, height: int, width: int, fov_x_deg: float, seed: int,
               max_tries: int = 200) -> Iterator[Camera]:
    """The cameras of :func:`sample_poses`, one at a time (a renderer draws them as it goes).
    The arguments are checked now, not at the first camera."""
    if n < 1:
        raise UserError(f"the number of views must be at least 1, got {n}")
    K = intrinsics_from_fov(width, height, fov_x_deg)
    return _poses(caster, n, K, height, width, np.random.default_rng(seed), max_tries)


def _poses(caster, n: int, K: np.ndarray, height: int, width: int, rng: np.random.Generator,
           max_tries: int) -> Iterator[Camera]:
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
            yield Camera(K, look_at(eye, target, scene.up), height, width)
            break
        else:
            raise UserError(f"could not place a camera in scene '{scene.name}' that sees the liver; check its camera region")


@dataclass
class Trajectory:
    """Per-frame cameras of a sequence plus its frame rate."""

    cameras: list[Camera]
    fps: float = 5.0

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
        return cls(cams, fps=fps if fps > 0 else 5.0)


def make_trajectory(
    caster, frames: int = 100, height: int = 256, width: int = 512, fov_x_deg: float = 75.0,
    seed: int = 0, keys: int = 5, fps: float = 5.0, max_tries: int = 50,
) -> Trajectory:
    """A smooth camera path that pans across the liver with varying distance."""
    from scipy.interpolate import CubicSpline

    if frames < 2:
        raise UserError(f"a trajectory needs at least 2 frames, got {frames}")
    scene = caster.scene
    K = intrinsics_from_fov(width, height, fov_x_deg)
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
            ok = caster.visible(eye, cand, liver)
            looks.append(cand[np.nonzero(ok)[0][0]] if ok.any() else None)
        if any(l is None for l in looks) or not caster.free_space(eyes).all():
            continue
        s = np.linspace(0.0, 1.0, keys)
        t = np.linspace(0.0, 1.0, frames)
        path_eye = scene.camera_region.clamp(CubicSpline(s, eyes, bc_type="natural")(t))
        path_look = CubicSpline(s, np.array(looks), bc_type="natural")(t)
        if not caster.free_space(path_eye).all():
            continue
        if np.min(np.linalg.norm(path_look - path_eye, axis=1)) < 15.0:
            continue
        cams = [Camera(K, look_at(e, l, scene.up), height, width) for e, l in zip(path_eye, path_look)]
        return Trajectory(cams, fps=fps)
    raise UserError(f"could not find a collision-free trajectory in scene '{scene.name}'; check its camera region")
