"""Classes as data: a scene with stomach, kidney, instrument and a user's own class imports,
renders, trains, translates and exports labels by its class table; old scenes and G-buffers
load with the paper's ids."""

import json

import numpy as np
import pytest
import trimesh
from PIL import Image
from train_data import real_dir, tiny_config

from sim2real.cli.main import main
from sim2real.render.gbuffer import GBuffer
from sim2real.render.raycast import RayCaster
from sim2real.scene.classes import ClassTable
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory, make_trajectory, sample_poses

H, W = 48, 96
TUMOUR_PALETTE = [255, 0, 255]
INSTRUMENT_PALETTE = [10, 20, 30]


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr()


def test_the_paper_ids_are_fixed_and_a_user_table_adds_after_every_default():
    t = ClassTable.defaults()
    assert [t[c].label for c in ("liver", "fat", "ligament", "abdominal_wall", "gallbladder")] == [0, 1, 2, 3, 4]
    assert len({c.label for c in t.values()}) == len(t)  # no two classes share an id
    u = t.with_entries({"tumour": {"a_ref": [0.6, 0.3, 0.3]}, "kidney": {"palette": [1, 2, 3]}})
    assert u["tumour"].label == max(c.label for c in t.values()) + 1
    assert u["kidney"].label == t["kidney"].label and u["kidney"].palette == (1, 2, 3)
    assert u["kidney"].a_ref == t["kidney"].a_ref
    with pytest.raises(Exception, match="fixed label id 0"):
        t.with_entries({"liver": {"label": 7}})
    with pytest.raises(Exception, match="share label id 9"):
        t.with_entries({"tumour": {"a_ref": [0.1, 0.1, 0.1], "label": 9}})


@pytest.fixture(scope="module")
def anatomy(tmp_path_factory):
    """A closed cavity (wall r 150 mm) with liver, stomach, two kidneys, an instrument and a tumour
    on the liver, as STL files named as CT segmentations name them; imported with a class table."""
    d = tmp_path_factory.mktemp("anatomy")
    parts = {
        "Liver": trimesh.creation.icosphere(subdivisions=3, radius=45.0),
        "Stomach": trimesh.creation.icosphere(subdivisions=2, radius=25.0).apply_translation([70, 10, 10]),
        "Kidney_left": trimesh.creation.icosphere(subdivisions=2, radius=18.0).apply_translation([-75, 0, 0]),
        "Kidney_right": trimesh.creation.icosphere(subdivisions=2, radius=18.0).apply_translation([75, -50, -20]),
        "instrument_grasper": trimesh.creation.cylinder(radius=4.0, height=70.0).apply_transform(
            trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])).apply_translation([25, 25, 70]),
        "tumour_1": trimesh.creation.icosphere(subdivisions=2, radius=12.0).apply_translation([0, 0, 42]),
    }
    wall = trimesh.creation.icosphere(subdivisions=3, radius=150.0)
    wall.invert()
    parts["Abdominal_wall"] = wall
    for name, mesh in parts.items():
        mesh.export(d / f"{name}.stl", file_type="stl")
    table = d / "classes.json"
    table.write_text(json.dumps({"classes": {"tumour": {"a_ref": [0.55, 0.45, 0.2], "palette": TUMOUR_PALETTE},
                                             "instrument": {"palette": INSTRUMENT_PALETTE}}}))
    return d, table


def test_a_scene_of_other_classes_imports_renders_trains_translates_and_exports(anatomy, tmp_path, capsys):
    from sim2real.engine.trainer import Trainer

    d, table = anatomy
    meshes = [a for p in sorted(d.glob("*.stl")) for a in ("--mesh", p)]
    code, io = cli(capsys, "scene", "import", *meshes, "--class-table", table, "--camera-region", "0,0,105,8,8,5",
                   "--out", tmp_path / "scene")
    assert code == 0, io.err
    spec = json.loads((tmp_path / "scene" / "scene.json").read_text())
    by_name = {o["name"]: o["class"] for o in spec["objects"]}
    assert by_name == {"Abdominal_wall": "abdominal_wall", "Kidney_left": "kidney", "Kidney_right": "kidney",
                       "Liver": "liver", "Stomach": "stomach", "instrument_grasper": "instrument", "tumour_1": "tumour"}
    labels = {c: e["label"] for c, e in spec["classes"].items()}
    assert labels == {"liver": 0, "abdominal_wall": 3, "stomach": 5, "kidney": 9, "instrument": 12, "tumour": 16}
    scene = Scene.load(tmp_path / "scene")

    # renders: label ids and a_ref colours follow the table
    caster = RayCaster(scene)
    cams = make_trajectory(caster, 4, H, W, seed=1).cameras
    g = caster.render(cams[0])
    assert set(np.unique(g.labels())) <= {0, 3, 5, 9, 12, 16, 255}
    tumour = g.labels() == 16
    assert tumour.any()  # the tumour on the liver's anterior side is in view

    # trains (tiny preset, 2 steps): the texture of each object starts at its class's a_ref colour
    cfg = tiny_config(iterations=2, checkpoint_every=2, log_every=1, image_every=2, device="cpu",
                      data__height=H, data__width=W)
    run = tmp_path / "run"
    trainer = Trainer(cfg, [tmp_path / "scene"], real_dir(tmp_path), run, progress=False)
    try:
        trainer.train()
    finally:
        trainer.close()

    # translates and exports
    Trajectory(cams, fps=5.0).save(tmp_path / "path.txt")
    out = tmp_path / "video"
    code, io = cli(capsys, "translate", run, "--scene", tmp_path / "scene", "--trajectory", tmp_path / "path.txt",
                   "--out", out, "--device", "cpu", "--no-progress")
    assert code == 0, io.err
    gt = out / "ground_truth"
    manifest = json.loads((gt / "ground_truth.json").read_text())
    assert manifest["classes"] == ["liver", "abdominal_wall", "stomach", "kidney", "instrument", "tumour"]
    assert manifest["label_palette"]["tumour"] == TUMOUR_PALETTE
    assert manifest["label_palette"]["instrument"] == INSTRUMENT_PALETTE
    lab = np.asarray(Image.open(gt / "labels" / "000000.png"))
    np.testing.assert_array_equal(lab, g.labels())
    colour = np.asarray(Image.open(gt / "labels_color" / "000000.png"))
    assert (colour[lab == 16] == TUMOUR_PALETTE).all()
    assert (colour[lab == 0] == [200, 40, 40]).all()  # the liver keeps the paper's palette

    # a trained run refuses a scene whose class colours it was not trained with
    spec["classes"]["tumour"]["a_ref"] = [0.1, 0.9, 0.1]
    (tmp_path / "scene" / "scene.json").write_text(json.dumps(spec))
    code, io = cli(capsys, "translate", run, "--scene", tmp_path / "scene", "--trajectory", tmp_path / "path.txt",
                   "--out", tmp_path / "video2", "--device", "cpu", "--no-progress")
    lines = [line for line in io.err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "class 'tumour'" in lines[0] and "a_ref" in lines[0]
    assert not (tmp_path / "video2" / "video.mp4").exists()


def test_the_stand_in_domain_gives_an_unknown_class_a_neutral_material_of_its_colour(anatomy, tmp_path, capsys):
    from sim2real.realdomain.appearance import Appearance, srgb_to_linear
    from sim2real.realdomain.materials import SceneMaterial

    d, table = anatomy
    meshes = [a for p in sorted(d.glob("*.stl")) for a in ("--mesh", p)]
    code, io = cli(capsys, "scene", "import", *meshes, "--class-table", table, "--camera-region", "0,0,105,8,8,5",
                   "--out", tmp_path / "scene")
    assert code == 0, io.err
    scene = Scene.load(tmp_path / "scene")
    k = [o.cls for o in scene.objects].index("tumour")
    mesh = scene.objects[k].mesh
    n = len(mesh.vertices)
    s = SceneMaterial(scene, Appearance.sample(0)).surface(
        np.full(n, k), np.asarray(mesh.vertices, np.float32), np.asarray(mesh.vertex_normals, np.float32),
        np.full(n, 0.5, np.float32))
    # mean albedo near the table's colour (linear light), mottled +-10 %
    np.testing.assert_allclose(s["albedo"].mean(axis=0), srgb_to_linear([0.55, 0.45, 0.2]), rtol=0.15)
    assert s["albedo"].std(axis=0).max() > 0


def test_old_scenes_and_view_files_load_with_the_paper_ids(procedural_scene, procedural_caster, tmp_path):
    procedural_scene.save(tmp_path / "new")
    spec = json.loads((tmp_path / "new" / "scene.json").read_text())
    for key in ("classes", "anterior", "source_units"):
        spec.pop(key)  # a scene folder written before classes were data
    (tmp_path / "new" / "scene.json").write_text(json.dumps(spec))
    old = Scene.load(tmp_path / "new")
    assert {c: old.class_table[c].label for c in old.class_table} == {
        "liver": 0, "fat": 1, "ligament": 2, "abdominal_wall": 3, "gallbladder": 4}
    np.testing.assert_array_equal(old.anterior, [0, 0, 1])
    g = procedural_caster.render(sample_poses(procedural_caster, 1, 32, 64, 75.0, seed=3)[0])
    g.save(tmp_path / "v.npz")
    with np.load(tmp_path / "v.npz") as z:  # a view file without the class table
        np.savez(tmp_path / "old.npz", **{k: z[k] for k in z.files if k != "class_table"})
    loaded = GBuffer.load(tmp_path / "old.npz")
    lut = np.array([("liver", "fat", "ligament", "abdominal_wall", "gallbladder").index(c) for c in g.classes] + [255])
    np.testing.assert_array_equal(loaded.labels(), lut[g.object_id])
