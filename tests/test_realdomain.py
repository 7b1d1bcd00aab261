"""The procedural stand-in for real laparoscopic video (sim2real.realdomain).

Checks: determinism (seed, worker count), labels = G-buffer classes, the same 3D point has the
same albedo from two views (through the ground-truth correspondences), and frame statistics that
separate the stand-in from the flat reference rendering a_ref.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from sim2real.errors import UserError
from sim2real.realdomain import Appearance, RenderOptions, SceneMaterial, derive_seed, make_real_domain, render_frame
from sim2real.realdomain.solid_texture import CellField, Noise, surface_samples
from sim2real.realdomain.vessel_tree import VesselTree
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.render.warp import correspondences, warp_image
from sim2real.scene.camera import Camera
from sim2real.scene.scene import CLASSES, LABEL_BACKGROUND
from sim2real.scene.trajectory import make_trajectory, sample_poses

H, W = 96, 192
SCENE_SEEDS = (1000, 1003)  # not the simulated domain's seeds


@pytest.fixture(scope="module")
def scene_dirs(tmp_path_factory):
    from sim2real.scene.procedural import generate_scene

    root = tmp_path_factory.mktemp("real_scenes")
    return [str(generate_scene(s).save(root / f"real_{s}")) for s in SCENE_SEEDS]


@pytest.fixture(scope="module")
def rigs(scene_dirs):
    from sim2real.scene.scene import Scene

    out = []
    for k, d in enumerate(scene_dirs):
        scene = Scene.load(d)
        out.append((RayCaster(scene), SceneMaterial(scene, Appearance.sample(derive_seed(0, 11, k)))))
    return out


@pytest.fixture(scope="module")
def frames(rigs):
    """Four random views per scene: (G-buffer, stand-in frame without sensor noise, a_ref uint8)."""
    out = []
    for k, (caster, material) in enumerate(rigs):
        for cam in sample_poses(caster, 4, H, W, 75.0, seed=100 + k):
            g = caster.render(cam)
            out.append((g, render_frame(g, material, RenderOptions(noise=0.0), seed=0), to_uint8(reference_rendering(g))))
    return out


@pytest.fixture(scope="module")
def run_one_worker(scene_dirs, tmp_path_factory):
    out = tmp_path_factory.mktemp("rd") / "w1"
    make_real_domain(scene_dirs, out, images=3, sequences=1, frames=3, seed=5, height=48, width=96,
                     workers=1, progress=False)
    return out


# --- determinism ------------------------------------------------------------------------------------


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_output_whatever_the_worker_count(scene_dirs, run_one_worker, tmp_path):
    make_real_domain(scene_dirs, tmp_path / "w2", images=3, sequences=1, frames=3, seed=5, height=48, width=96,
                     workers=2, progress=False)
    a, b = _files(run_one_worker), _files(tmp_path / "w2")
    assert a.keys() == b.keys()
    assert len([k for k in a if k.endswith(".png")]) == 2 * (3 + 3)
    for k in a:
        assert a[k] == b[k], k


def test_other_seed_other_output(scene_dirs, run_one_worker, tmp_path):
    make_real_domain(scene_dirs[:1], tmp_path / "s6", images=1, seed=6, height=48, width=96, workers=1,
                     progress=False)
    assert (tmp_path / "s6" / "images" / "000000.png").read_bytes() != (run_one_worker / "images" / "000000.png").read_bytes()
    assert Appearance.sample(1) != Appearance.sample(2)
    assert Appearance.sample(1) == Appearance.sample(1)


def test_frame_depends_only_on_its_seed(rigs, frames):
    g, f, _ = frames[0]
    again = render_frame(g, rigs[0][1], RenderOptions(noise=0.0), seed=123)
    np.testing.assert_array_equal(again.image, f.image)  # no noise: the seed does not matter
    n1 = render_frame(g, rigs[0][1], RenderOptions(), seed=1).image
    assert np.array_equal(n1, render_frame(g, rigs[0][1], RenderOptions(), seed=1).image)
    assert not np.array_equal(n1, render_frame(g, rigs[0][1], RenderOptions(), seed=2).image)


def test_appearance_varies_mildly():
    looks = [Appearance.sample(s) for s in range(20)]
    liver = np.array([a.liver for a in looks])
    assert liver.std(axis=0).max() > 0.005  # a distribution, not one look
    assert np.all(liver[:, 0] > liver[:, 1])  # ... of red-brown livers
    fat = np.array([a.fat for a in looks])
    assert np.all((fat[:, 0] > fat[:, 1]) & (fat[:, 1] > fat[:, 2]))  # yellow-orange
    dens = [a.vessel_density for a in looks]
    assert 0.6 < min(dens) < max(dens) < 1.4
    a = looks[3]
    assert Appearance(**{k: tuple(v) if isinstance(v, list) else v for k, v in a.to_json().items()}) == a


# --- outputs: labels, manifest, sequences ------------------------------------------------------------


def test_labels_agree_with_gbuffer_object_ids(frames):
    for g, f, _ in frames:
        lut = np.array([CLASSES.index(c) for c in g.classes])
        expected = np.where(g.object_id >= 0, lut[np.maximum(g.object_id, 0)], LABEL_BACKGROUND)
        np.testing.assert_array_equal(f.label, expected)
        assert f.label.dtype == np.uint8


def test_label_files_read_back_as_class_indices(scene_dirs, run_one_worker):
    from sim2real.scene.scene import Scene

    m = json.loads((run_one_worker / "manifest.json").read_text())
    assert m["labels"]["classes"] == list(CLASSES) and m["labels"]["background"] == 255
    for entry in m["frames"]:
        label = np.asarray(Image.open(run_one_worker / entry["label"]))
        image = np.asarray(Image.open(run_one_worker / entry["image"]))
        assert label.ndim == 2 and label.dtype == np.uint8 and image.shape == label.shape + (3,)
        caster = RayCaster(Scene.load(scene_dirs[entry["scene"]]))
        cam = Camera(np.array(entry["K"]), np.array(entry["world_to_camera"]), 48, 96)
        np.testing.assert_array_equal(label, caster.render(cam).labels())
        assert set(np.unique(label)) <= set(range(len(CLASSES))) | {255}


def test_manifest_and_sequences(run_one_worker):
    m = json.loads((run_one_worker / "manifest.json").read_text())
    assert m["format"] == "sim2real-realdomain/1" and m["seed"] == 5
    assert [s["scene_seed"] for s in m["scenes"]] == list(SCENE_SEEDS)
    assert [f["scene"] for f in m["frames"]] == [0, 1, 0]  # spread over the scenes
    assert len({f["pose_seed"] for f in m["frames"]}) == 3
    (seq,) = m["sequence_list"]
    assert (run_one_worker / seq["trajectory"]).is_file()
    centres = [-np.array(f["world_to_camera"])[:3, :3].T @ np.array(f["world_to_camera"])[:3, 3] for f in seq["frames"]]
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert len(centres) == 3 and np.all(steps < 60.0)  # consecutive frames of one smooth path
    for f in seq["frames"]:
        assert (run_one_worker / seq["dir"] / f["image"]).is_file() and (run_one_worker / seq["dir"] / f["label"]).is_file()
    assert m["render"]["height"] == 48 and "appearance" in m["scenes"][0]


def test_endoscope_mask(frames, rigs):
    g = frames[0][0]
    f = render_frame(g, rigs[0][1], RenderOptions(mask=True), seed=0)
    corner = (slice(0, 4), slice(0, 4))
    assert np.all(f.image[corner] == 0) and np.all(f.label[corner] == LABEL_BACKGROUND)
    np.testing.assert_array_equal(f.label[H // 2], g.labels()[H // 2])


# --- appearance is defined in 3D ------------------------------------------------------------------


def test_same_point_same_albedo_from_two_views(rigs):
    caster, material = rigs[0]
    traj = make_trajectory(caster, 12, H, W, 75.0, seed=3, flow_budget=None, max_deg_per_frame=None, look="swing")
    gi, gj = caster.render(traj.cameras[0]), caster.render(traj.cameras[1])  # ~1 cm apart
    fi = render_frame(gi, material, RenderOptions(noise=0.0), seed=0)
    fj = render_frame(gj, material, RenderOptions(noise=0.0), seed=0)
    uv, visible = correspondences(gi, gj)
    # Away from silhouettes (bilinear sampling would mix objects there).
    edges = cv2.dilate((cv2.Laplacian(gj.object_id.astype(np.float32), cv2.CV_32F) != 0).astype(np.uint8), np.ones((5, 5), np.uint8))
    ok = visible & (warp_image(edges.astype(np.float32), uv, visible) == 0)
    assert ok.sum() > 0.3 * H * W
    # Lighting factored out: the albedo buffer is what the lit radiance is divided by.
    lit = fi.shading > 0.05
    recovered = (fi.radiance - fi.specular[..., None] * np.array([1.0, 0.97, 0.92], np.float32)) / np.maximum(fi.shading, 1e-6)[..., None]
    np.testing.assert_allclose(recovered[lit], fi.albedo[lit], atol=1e-4)
    warped = warp_image(fj.albedo, uv, visible)
    diff = np.abs(warped - fi.albedo)[ok].max(axis=-1)
    shifted = np.abs(warp_image(fj.albedo, uv + np.float32([6.0, 0.0]), visible) - fi.albedo)[ok].max(axis=-1)
    assert np.median(diff) < 0.004 and np.mean(diff) < 0.01, (np.median(diff), np.mean(diff))
    assert np.mean(shifted) > 3 * np.mean(diff)  # the comparison has power
    # The albedo of a lit view differs from the image: lighting did change between the views.
    assert np.mean(np.abs(warp_image(fj.radiance, uv, visible) - fi.radiance)[ok]) > np.mean(diff)


def test_material_is_a_function_of_the_point(rigs, frames):
    g = frames[1][0]
    material = rigs[0][1]
    hit = np.nonzero(g.mask.reshape(-1))[0]
    ids = g.object_id.reshape(-1)[hit]
    pts = g.points.reshape(-1, 3)[hit]
    nrm = g.normal.reshape(-1, 3)[hit]
    fp = np.full(len(hit), 0.3, np.float32)
    a = material.surface(ids, pts, nrm, fp)["albedo"]
    perm = np.random.default_rng(0).permutation(len(hit))[: len(hit) // 3]
    b = material.surface(ids[perm], pts[perm], nrm[perm], fp[perm])["albedo"]
    np.testing.assert_array_equal(a[perm], b)


# --- frame statistics against the flat reference rendering ------------------------------------------


def _interior(g, classes):
    """Pixels of ``classes`` at least 3 px from silhouettes, class borders and depth jumps."""
    cls = g.class_index().astype(np.float32)
    d = g.distance.astype(np.float32)
    jump = (np.abs(np.diff(d, axis=1, append=d[:, -1:])) + np.abs(np.diff(d, axis=0, append=d[-1:]))) > 0.03 * np.maximum(d, 1.0)
    border = cv2.morphologyEx(cls, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    near = cv2.dilate((jump | border).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    return np.isin(g.class_index(), classes) & ~near


def _high_frequency(image):
    green = image[..., 1].astype(np.float32) / 255.0  # red vessels on pink/yellow show in green
    return np.abs(green - cv2.GaussianBlur(green, (0, 0), 1.5))


def test_vessels_give_high_frequency_detail_on_wall_and_fat(frames):
    wall_fat = [CLASSES.index("abdominal_wall"), CLASSES.index("fat")]
    ours, ref = [], []
    for g, f, a_ref in frames:
        m = _interior(g, wall_fat)
        ours.append(_high_frequency(f.image)[m])
        ref.append(_high_frequency(a_ref)[m])
    ours, ref = np.concatenate(ours), np.concatenate(ref)
    assert len(ours) > 10_000
    share_ours, share_ref = (ours > 0.02).mean(), (ref > 0.02).mean()
    assert share_ours > 0.02 and share_ours > 5 * share_ref, (share_ours, share_ref)


def test_brightness_falls_off_from_the_centre(frames):
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot((xx + 0.5 - W / 2) / (W / 2), (yy + 0.5 - H / 2) / (H / 2))
    centre, border = r < 0.4, r > 0.8
    ours = [f.image.mean(-1)[centre].mean() / f.image.mean(-1)[border].mean() for _, f, _ in frames]
    refs = [a.mean(-1)[centre].mean() / max(a.mean(-1)[border].mean(), 1.0) for _, _, a in frames]
    assert np.mean(ours) > 1.1 and np.mean(ours) > 1.3 * np.mean(refs), (ours, refs)
    # The illumination itself (albedo factored out): brightest in the centre of the view.
    light = [f.shading[centre & g.mask].mean() / f.shading[border & g.mask].mean() for g, f, _ in frames]
    assert min(light) > 1.0 and np.mean(light) > 1.5, light


def test_specular_highlights_exist_but_are_rare(frames):
    spec = []
    for _, f, a_ref in frames:
        im = f.image.astype(np.float32) / 255.0
        spec.append((im.min(-1) > 0.8) & (im.max(-1) - im.min(-1) < 0.25))  # near-white glints
        ref = a_ref.astype(np.float32) / 255.0
        assert not ((ref.min(-1) > 0.8) & (ref.max(-1) - ref.min(-1) < 0.25)).any()
    spec = np.stack(spec)
    assert spec.sum() >= 5, spec.sum()
    assert spec.mean() < 0.02 and max(s.mean() for s in spec) < 0.05


# --- bad inputs ---------------------------------------------------------------------------------------


def _cli(argv, capsys):
    from sim2real.cli.main import COMMANDS

    if "realdomain" in COMMANDS:
        from sim2real.cli.main import main

        code = main(argv)
    else:  # the lead's main.py lists the command; keep the test independent of it
        import argparse

        from sim2real.cli import realdomain

        parser = argparse.ArgumentParser()
        realdomain.register(parser.add_subparsers(dest="command"))
        args = parser.parse_args(argv)
        try:
            code = args.func(args)
        except UserError as e:
            print(f"sim2real: error: {e}", file=__import__("sys").stderr)
            code = 2
    err = capsys.readouterr().err.strip()
    return code, err


def test_cli_bad_inputs_are_one_line_errors(scene_dirs, tmp_path, capsys):
    code, err = _cli(["realdomain", "--scenes", str(tmp_path / "nope"), "--images", "2", "--out", str(tmp_path / "o1"), "--quiet"], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "does not exist" in err
    assert not (tmp_path / "o1").exists()
    code, err = _cli(["realdomain", "--scenes", scene_dirs[0], "--images", "0", "--out", str(tmp_path / "o2"), "--quiet"], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "at least 1" in err
    (tmp_path / "o3").mkdir()
    (tmp_path / "o3" / "old.png").write_bytes(b"x")
    code, err = _cli(["realdomain", "--scenes", scene_dirs[0], "--images", "1", "--out", str(tmp_path / "o3"), "--quiet"], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "already holds" in err
    code, err = _cli(["realdomain", "--scenes", scene_dirs[0], "--images", "1", "--sequences", "1", "--frames", "1",
                      "--out", str(tmp_path / "o4"), "--quiet"], capsys)
    assert code == 2 and "at least 2 frames" in err
    with pytest.raises(UserError):
        make_real_domain([], tmp_path / "o5", images=1)


def test_cli_writes_a_dataset(scene_dirs, tmp_path, capsys):
    code, _ = _cli(["realdomain", "--scenes", scene_dirs[1], "--images", "2", "--out", str(tmp_path / "ok"),
                    "--height", "32", "--width", "64", "--seed", "9", "--mask", "--workers", "1", "--quiet"], capsys)
    assert code == 0
    assert sorted(p.name for p in (tmp_path / "ok" / "images").iterdir()) == ["000000.png", "000001.png"]
    m = json.loads((tmp_path / "ok" / "manifest.json").read_text())
    assert m["render"]["mask"] is True and m["seed"] == 9


# --- solid texture building blocks -------------------------------------------------------------


def test_noise_gradient_matches_finite_differences():
    noise = Noise(4)
    p = np.random.default_rng(0).uniform(-50, 50, (64, 3))
    v, g = noise.fbm(p, 7.0, 3, grad=True)
    e = 1e-2
    num = np.stack([(noise.fbm(p + e * np.eye(3)[a], 7.0, 3) - noise.fbm(p - e * np.eye(3)[a], 7.0, 3)) / (2 * e)
                    for a in range(3)], axis=1)
    np.testing.assert_allclose(g, num, atol=2e-3 * np.abs(g).max())
    assert 0.6 < noise.fbm(np.random.default_rng(1).uniform(0, 500, (20000, 3)), 10.0, 4).std() < 1.5


def test_cell_edges_are_distances_to_the_voronoi_face():
    rng = np.random.default_rng(0)
    samples = rng.uniform(0, 40, (2000, 3))
    field = CellField(samples, 6.0, seed=1)
    q = rng.uniform(5, 35, (500, 3))
    cq = field.query(q)
    d = np.linalg.norm(q[:, None] - field.points[None], axis=-1)
    order = np.argsort(d, axis=1)
    c1, c2 = field.points[order[:, 0]], field.points[order[:, 1]]
    n = (c1 - c2) / np.linalg.norm(c1 - c2, axis=1, keepdims=True)
    expected = np.einsum("ij,ij->i", q - 0.5 * (c1 + c2), n)
    np.testing.assert_allclose(cq.edge, expected, atol=1e-4)
    np.testing.assert_allclose(cq.f1, d[np.arange(500), order[:, 0]], atol=1e-4)


def test_vessel_tree_is_a_forest_with_tapering_calibres():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=60.0)
    samples = surface_samples(np.asarray(sphere.vertices), np.asarray(sphere.faces), 2.0, seed=0)
    tree = VesselTree(samples, 5.0, seed=2, r_leaf=0.1, r_max=1.0, prune=3)
    assert 0 < len(tree) < len(tree.nodes)  # a forest has fewer edges than nodes
    big = tree.flow > np.percentile(tree.flow, 90)
    assert tree.radius[big].mean() > 2 * tree.radius[~big].mean()
    assert tree.radius.max() <= 1.0 + 1e-6
    q = samples[::50]
    d, r, _ = tree.query(q)
    ab = tree.b - tree.a
    t = np.clip(np.einsum("ijk,jk->ij", q[:, None] - tree.a[None], ab) / np.einsum("jk,jk->j", ab, ab), 0, 1)
    brute = np.linalg.norm(q[:, None] - (tree.a[None] + t[..., None] * ab[None]), axis=-1).min(axis=1)
    close = brute < 2.0  # the nearest segment is found where a vessel can be visible
    np.testing.assert_allclose(d[close], brute[close], atol=1e-3)
    assert np.all(d >= brute - 1e-6)
