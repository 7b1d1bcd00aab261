"""Procedural abdominal scenes: liver, gallbladder, falciform ligament, fat/stomach, abdominal wall.

World frame (mm): x towards the patient's left, y towards the head (cranial), z anterior
(towards the abdominal wall the camera enters through). Random views look roughly along -z.

Every organ starts as an icosphere whose radius is a positive smooth function of direction
(lobes plus surface detail), so the surface is star-shaped and embedded. It is then bent by
maps that are bijections of space (anisotropic scaling, a thickness wedge, a flattened
underside, a dome shear). A bijection cannot make a surface cut itself, so every mesh stays
free of self-intersections and watertight, whatever the seed.
"""

from __future__ import annotations

import numpy as np
import trimesh

from sim2real.scene.scene import CameraRegion, Scene, SceneObject


def _bumps(rng: np.random.Generator, n: int, amp: tuple[float, float], width: tuple[float, float]):
    centres = rng.normal(size=(n, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    return centres, rng.uniform(*amp, size=n) * rng.choice([-1.0, 1.0], size=n), rng.uniform(*width, size=n)


def _radial(dirs: np.ndarray, bumps) -> np.ndarray:
    """Sum of Gaussian bumps on the sphere: sum_m a_m exp(-(1 - d.c_m) / w_m^2)."""
    centres, amps, widths = bumps
    return (amps[None] * np.exp(-(1.0 - dirs @ centres.T) / widths[None] ** 2)).sum(axis=1)


def _blob(rng: np.random.Generator, subdivisions: int, lobes: int, lobe_amp: float, detail: float) -> trimesh.Trimesh:
    """Unit-size star-shaped blob: radius 1 + large lobes + fine surface detail, clipped > 0.35."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = np.asarray(sphere.vertices)
    r = 1.0
    r = r + _radial(d, _bumps(rng, lobes, (0.3 * lobe_amp, lobe_amp), (0.5, 0.9)))
    r = r + _radial(d, _bumps(rng, 40, (0.3 * detail, detail), (0.12, 0.25)))
    r = r + _radial(d, _bumps(rng, 120, (0.2 * detail, 0.5 * detail), (0.05, 0.1)))
    r = np.maximum(r, 0.35)
    return trimesh.Trimesh(d * r[:, None], np.asarray(sphere.faces), process=False)


def _liver(rng: np.random.Generator, centre: np.ndarray) -> trimesh.Trimesh:
    m = _blob(rng, 5, lobes=4, lobe_amp=0.18, detail=0.035)
    v = np.asarray(m.vertices).copy()
    semi = np.array([rng.uniform(95, 115), rng.uniform(70, 85), rng.uniform(36, 44)])
    v *= semi
    # Wedge: the right lobe (x < 0) is thick, the left lobe thins out.
    v[:, 2] *= 0.45 + 0.55 / (1.0 + np.exp(v[:, 0] / rng.uniform(30, 45)))
    # Flatter visceral (under) side, convex diaphragmatic (upper) side.
    v[:, 2] = np.where(v[:, 2] < 0, 0.6 * v[:, 2], v[:, 2])
    v[:, 2] -= (v[:, 0] / semi[0]) ** 2 * rng.uniform(10, 18) + (v[:, 1] / semi[1]) ** 2 * rng.uniform(6, 12)
    # A mild twist about the cranio-caudal axis, so each liver leans differently.
    v[:, 2] += v[:, 0] * rng.uniform(-0.08, 0.08)
    return trimesh.Trimesh(v + centre, m.faces, process=False)


def _gallbladder(rng: np.random.Generator, liver: trimesh.Trimesh) -> trimesh.Trimesh:
    m = _blob(rng, 4, lobes=2, lobe_amp=0.08, detail=0.02)
    v = np.asarray(m.vertices).copy()
    v *= np.array([rng.uniform(14, 18), rng.uniform(38, 46), rng.uniform(14, 18)])
    # Pear shape: the fundus (y < 0 end) is wider than the neck.
    v[:, [0, 2]] *= (1.0 - 0.3 * (v[:, 1:2] / 45.0))
    lo, hi = liver.bounds
    tilt = np.radians(rng.uniform(15, 30))
    rot = trimesh.transformations.rotation_matrix(tilt, [1, 0, 0])[:3, :3]
    v = v @ rot.T
    # Under the right lobe, its fundus reaching past the liver's inferior edge.
    centre = np.array([lo[0] + (hi[0] - lo[0]) * rng.uniform(0.28, 0.4), lo[1] + rng.uniform(18, 28), lo[2] + 0.3 * (hi[2] - lo[2])])
    return trimesh.Trimesh(v + centre, m.faces, process=False)


def _wall(rng: np.random.Generator, centre: np.ndarray, radii: np.ndarray) -> trimesh.Trimesh:
    """Closed shell: an inner, displaced cavity surface facing inwards and an outer surface."""
    sphere = trimesh.creation.icosphere(subdivisions=5)
    d = np.asarray(sphere.vertices)
    r_in = 1.0 + _radial(d, _bumps(rng, 30, (0.005, 0.02), (0.15, 0.35)))
    inner = d * r_in[:, None] * radii + centre
    outer = d * 1.0 * (radii + 25.0) + centre
    faces = np.asarray(sphere.faces)
    n = len(d)
    verts = np.vstack([outer, inner])
    # Inner faces reversed, so their normals point into the cavity (outward of the wall solid).
    all_faces = np.vstack([faces, faces[:, ::-1] + n])
    return trimesh.Trimesh(verts, all_faces, process=False)


def _ligament(rng: np.random.Generator, liver: trimesh.Trimesh, wall_centre, wall_radii) -> trimesh.Trimesh:
    """Falciform ligament: a thin curved sheet from the liver's upper surface to the wall."""
    lo, hi = liver.bounds
    x0 = lo[0] + (hi[0] - lo[0]) * rng.uniform(0.55, 0.65)
    y0, y1 = lo[1] + 0.55 * (hi[1] - lo[1]), hi[1] - 5.0
    z0 = 0.5 * (lo[2] + hi[2])
    z1 = wall_centre[2] + wall_radii[2] + 10.0
    box = trimesh.creation.box(extents=[rng.uniform(1.5, 2.5), y1 - y0, z1 - z0])
    box = box.subdivide_to_size(max_edge=6.0)
    v = np.asarray(box.vertices).copy()
    v += np.array([x0, 0.5 * (y0 + y1), 0.5 * (z0 + z1)])
    # Sideways sway (a shear along x: a bijection, so the sheet stays embedded).
    v[:, 0] += rng.uniform(3, 8) * np.sin((v[:, 1] - y0) / rng.uniform(30, 50)) + 0.08 * (v[:, 2] - z0)
    return trimesh.Trimesh(v, box.faces, process=False)


def _fat(rng: np.random.Generator, liver: trimesh.Trimesh) -> trimesh.Trimesh:
    """Stomach under the left lobe and lobular omental fat in the lower abdomen (disjoint closed parts)."""
    lo, hi = liver.bounds
    parts = []
    stomach = _blob(rng, 4, lobes=3, lobe_amp=0.15, detail=0.05)
    sv = np.asarray(stomach.vertices) * np.array([rng.uniform(55, 70), rng.uniform(60, 75), rng.uniform(40, 50)])
    sv += np.array([hi[0] + rng.uniform(-10, 15), lo[1] + rng.uniform(30, 50), lo[2] - 25.0])
    parts.append(trimesh.Trimesh(sv, stomach.faces, process=False))
    for _ in range(int(rng.integers(3, 6))):
        blob = _blob(rng, 4, lobes=5, lobe_amp=0.25, detail=0.08)
        bv = np.asarray(blob.vertices) * rng.uniform(40, 70, size=3) * np.array([1.0, 1.0, 0.7])
        bv += np.array([rng.uniform(-110, 110), rng.uniform(-170, -50), rng.uniform(-90, -45)])
        parts.append(trimesh.Trimesh(bv, blob.faces, process=False))
    return trimesh.util.concatenate(parts)


def generate_scene(seed: int, name: str | None = None) -> Scene:
    """A plausible abdominal scene; the same seed always gives the same scene."""
    rng = np.random.default_rng(seed)
    wall_centre = np.array([0.0, 20.0, -20.0])
    wall_radii = np.array([rng.uniform(195, 215), rng.uniform(215, 235), rng.uniform(125, 140)])
    liver_centre = np.array([rng.uniform(-30, -10), rng.uniform(60, 80), rng.uniform(-30, -20)])
    liver = _liver(rng, liver_centre)
    gallbladder = _gallbladder(rng, liver)
    ligament = _ligament(rng, liver, wall_centre, wall_radii)
    fat = _fat(rng, liver)
    wall = _wall(rng, wall_centre, wall_radii)
    lo, hi = liver.bounds
    # Cameras hover in front of (anterior to) the liver, below the wall.
    region = CameraRegion(
        center=[0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]) - 35.0, hi[2] + 50.0],
        radii=[65.0, 45.0, 22.0],
    )
    objects = [
        SceneObject("liver", "liver", liver),
        SceneObject("fat", "fat", fat),
        SceneObject("ligament", "ligament", ligament),
        SceneObject("abdominal_wall", "abdominal_wall", wall),
        SceneObject("gallbladder", "gallbladder", gallbladder),
    ]
    return Scene(
        name=name or f"procedural_{seed:04d}",
        objects=objects,
        camera_region=region,
        up=np.array([0.0, 1.0, 0.0]),
        metadata={"generator": "sim2real.scene.procedural", "seed": int(seed)},
    )
