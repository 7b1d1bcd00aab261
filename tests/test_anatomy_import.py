"""Importing the user's own anatomy: units, smooth normals, negative coordinates, escaping rays,
``--camera-region auto``, ``scene preview`` and the one-line refusals of bad input."""

import json

import numpy as np
import trimesh
from PIL import Image

from sim2real.cli.main import main
from sim2real.render.raycast import RayCaster, check_camera_region
from sim2real.render.reference import FALLOFF, reference_rendering
from sim2real.render.region import fit_camera_region
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import sample_poses


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr()


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _stl(path, mesh):
    mesh.export(path, file_type="stl")  # STL: every triangle with its own 3 vertices, no vertex normals
    return path


def _organs(tmp_path, scale=1.0):
    """A liver ball (r 40 mm) inside a closed wall (r 150 mm), as STL files in units of 1/scale mm."""
    liver = trimesh.creation.icosphere(subdivisions=2, radius=40.0)
    wall = trimesh.creation.icosphere(subdivisions=2, radius=150.0)
    wall.invert()
    for m in (liver, wall):
        m.apply_scale(scale)
    return _stl(tmp_path / "Liver.stl", liver), _stl(tmp_path / "Abdominal_wall.stl", wall)


def test_metre_scale_meshes_are_refused_naming_the_unit_and_import_with_units_m(tmp_path, capsys):
    liver_m, wall_m = _organs(tmp_path, scale=1e-3)
    out = tmp_path / "s"
    code, io = cli(capsys, "scene", "import", "--mesh", liver_m, "--mesh", wall_m, "--camera-region", "0,0,90,5,5,5",
                   "--out", out)
    line = one_line(io.err)
    assert code == 2 and "0.08 mm across" in line and "--units m" in line  # 2 x 40 mm x 1e-3
    assert not out.exists()
    code, io = cli(capsys, "scene", "import", "--mesh", liver_m, "--mesh", wall_m, "--camera-region", "0,0,90,5,5,5",
                   "--units", "m", "--out", out)
    assert code == 0, io.err
    assert "(2 objects: " in io.out
    scene = Scene.load(out)
    assert json.loads((out / "scene.json").read_text())["source_units"] == "m"
    liver = scene.objects[scene.objects_of("liver")[0]].mesh
    # stored in mm: the icosphere's vertices lie on the 40 mm sphere
    np.testing.assert_allclose(np.linalg.norm(liver.vertices, axis=1), 40.0, rtol=1e-5)
    code, io = cli(capsys, "scene", "import", "--mesh", liver_m, "--mesh", wall_m, "--camera-region", "0,0,90,5,5,5",
                   "--units", "cm", "--out", tmp_path / "s_cm")
    assert code == 2 and "probably in m" in one_line(io.err)


def _sphere_view(scene_dir):
    scene = Scene.load(scene_dir)
    K = intrinsics_from_fov(96, 96, 60.0)
    cam = Camera(K, look_at(np.array([0.0, 0.0, 110.0]), np.zeros(3), scene.up), 96, 96)
    return RayCaster(scene).render(cam)


def _diffs(a):
    """First differences down and across, both cropped to (H-1, W-1)."""
    return np.diff(a, axis=0)[:, :-1], np.diff(a, axis=1)[:-1, :]


def _gradient_error(a_ref, exact, inner):
    """Mean |first difference of a_ref - that of the exact sphere| down and across."""
    m = inner[:-1, :-1]
    return float(np.mean([np.abs(x - y)[m].mean() for x, y in zip(_diffs(a_ref), _diffs(exact))]))


def test_smooth_normals_remove_the_facets_of_a_tessellated_sphere(tmp_path, capsys):
    liver, wall = _organs(tmp_path)  # icosphere of 320 triangles, about 12 mm (10 px here) each
    for name, extra in (("smooth", []), ("flat", ["--flat-normals"])):
        code, io = cli(capsys, "scene", "import", "--mesh", liver, "--mesh", wall, "--camera-region", "0,0,110,5,5,5",
                       "--out", tmp_path / name, *extra)
        assert code == 0, io.err
    smooth, flat = _sphere_view(tmp_path / "smooth"), _sphere_view(tmp_path / "flat")
    on_liver = smooth.object_id == 0
    assert on_liver.sum() > 1000 and np.array_equal(on_liver, flat.object_id == 0)
    inner = on_liver & np.roll(on_liver, -1, 0) & np.roll(on_liver, -1, 1)
    # the exact sphere's a_ref (red channel), from the true normal of each hit point: independent
    # of the mesh's normals
    p = smooth.points.astype(np.float64)
    to_cam = np.array([0.0, 0.0, 110.0]) - p
    cos = np.einsum("hwc,hwc->hw", p / np.linalg.norm(p, axis=-1, keepdims=True),
                    to_cam / np.linalg.norm(to_cam, axis=-1, keepdims=True))
    d = np.minimum(smooth.distance, 100.0)
    exact = 0.34 * (0.9 * np.clip(cos, 0, 1) + 0.1) / (FALLOFF[0] * d * d + FALLOFF[1] * d + FALLOFF[2])
    scale = float(np.mean([np.abs(x)[inner[:-1, :-1]].mean() for x in _diffs(exact)]))
    e_smooth = _gradient_error(reference_rendering(smooth)[..., 0], exact, inner)
    e_flat = _gradient_error(reference_rendering(flat)[..., 0], exact, inner)
    # flat facets: a_ref is constant-ish inside a triangle and jumps at its edges, an error as
    # large as the gradient itself (measured: 1.0x); smooth normals follow the sphere (0.02x)
    assert e_flat > 0.5 * scale
    assert e_smooth < 0.1 * scale


def test_negative_coordinates_need_no_equals_sign(tmp_path, capsys):
    liver, wall = _organs(tmp_path)
    code, io = cli(capsys, "scene", "import", "--mesh", liver, "--mesh", wall, "--camera-region", "-60,-60,60,5,5,5",
                   "--up", "-1,0,0", "--anterior", "0,0,1", "--out", tmp_path / "s")
    assert code == 0, io.err
    scene = Scene.load(tmp_path / "s")
    np.testing.assert_allclose(scene.camera_region.center, [-60, -60, 60])
    np.testing.assert_allclose(scene.up, [-1, 0, 0])


def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys):
    liver, wall = _organs(tmp_path)
    table = tmp_path / "classes.json"
    table.write_text(json.dumps({"classes": {"tumour": {"a_ref": [0.5, 1.7, 0.2]}}}))
    cases = [
        (["--mesh", liver, "--class-table", table, "--camera-region", "0,0,90,5,5,5"], "a_ref of class 'tumour'"),
        (["--mesh", liver, "--camera-region", "0,0,0,5,5,5"], "inside organ 'Liver'"),  # the region sits in the liver
        (["--mesh", liver, "--camera-region", "-10,0,0,5,5,5"], "inside organ 'Liver'"),
        (["--mesh", f"{liver}=spleenish", "--camera-region", "0,0,90,5,5,5"], "unknown class 'spleenish'"),
        (["--mesh", f"{liver}=Liver", "--camera-region", "0,0,90,5,5,5"], "unknown class 'Liver'"),
    ]
    for extra, words in cases:
        out = tmp_path / "out"
        code, io = cli(capsys, "scene", "import", "--mesh", wall, *extra, "--out", out)
        assert code == 2 and words in one_line(io.err), (extra, io.err)
        assert not out.exists()


def test_camera_region_auto_keeps_cameras_in_the_cavity(procedural_scene, procedural_caster):
    region = fit_camera_region(procedural_caster)
    pts = region.sample(np.random.default_rng(1), 400)
    # free space: outside every organ and inside the wall, for (nearly) every point of the region
    assert procedural_caster.free_space(pts).mean() >= 0.97
    assert (procedural_caster.containing_object(pts) < 0).mean() >= 0.97
    # anterior of the liver, as the procedural scenes' own regions are
    liver = procedural_scene.objects[procedural_scene.objects_of("liver")[0]].mesh
    assert region.center[2] > liver.bounds.mean(axis=0)[2]
    auto = Scene(procedural_scene.name, procedural_scene.objects, region)
    caster = RayCaster(auto)
    check_camera_region(auto, caster)
    cams = sample_poses(caster, 4, 32, 64, 75.0, seed=0)
    assert caster.free_space(np.array([c.camera_to_world[:3, 3] for c in cams])).all()


def test_scene_preview_and_escaping_rays(tmp_path, capsys):
    # an open scene: a 200 mm liver plate, no wall; cameras that look past its edge see background
    plate = trimesh.creation.box(extents=[200.0, 200.0, 10.0])
    for _ in range(4):
        plate = plate.subdivide()  # vertices all over the top: look-at targets near the edges and the middle
    _stl(tmp_path / "Liver.stl", plate)
    code, io = cli(capsys, "scene", "import", "--mesh", tmp_path / "Liver.stl", "--camera-region", "0,0,60,90,90,20",
                   "--out", tmp_path / "s")
    assert code == 0, io.err
    code, io = cli(capsys, "scene", "check", tmp_path / "s", "--views", 16)
    assert code == 0 and "background (escaping rays) per random view" in io.out
    code, io = cli(capsys, "render", tmp_path / "s", "--views", 6, "--height", 32, "--width", 64, "--workers", 1,
                   "--out", tmp_path / "views")
    assert code == 0, io.err
    assert "random views skipped: more than 30% background" in io.out
    from sim2real.render.gbuffer import GBuffer

    shares = [1 - GBuffer.load(p).mask.mean() for p in sorted((tmp_path / "views").glob("view_*.npz"))]
    assert len(shares) == 6 and max(shares) <= 0.35  # the probe grid is coarser than the view
    code, io = cli(capsys, "scene", "preview", tmp_path / "s", "--out", tmp_path / "sheet.png", "--views", 4,
                   "--frames", 4, "--height", 32, "--width", 64)
    assert code == 0, io.err
    sheet = np.asarray(Image.open(tmp_path / "sheet.png"))
    assert sheet.shape == (2 * 32 + 2, 4 * 64 + 3 * 2, 3)  # two rows of four tiles, 2 px gaps
    assert sheet[:32, :64].max() > 0  # a_ref of the plate, not black
