"""Downstream odometry: hand-checkable pose algebra, and on a path of a scene the perfect video
(the stand-in's ceiling) recovers the camera's rotation while the flickering floor fails."""

import numpy as np
import pytest
from train_data import scene_dir

from sim2real.inference.anchors import Anchors
from sim2real.metrics.consistency import orb_settings_for
from sim2real.metrics.odometry import (
    direction_error_deg,
    ground_truth_motion,
    odometry,
    odometry_orb,
    pair_starts,
    rotation_error_deg,
    summarise,
)
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import make_trajectory


def rot_z(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])


def test_pose_algebra_by_hand():
    wa, wb = np.eye(4), np.eye(4)
    wb[:3, :3], wb[:3, 3] = rot_z(10), [3.0, 0, 4.0]
    R, t = ground_truth_motion(wa, wb)
    assert np.allclose(R, rot_z(10)) and np.allclose(t, [3, 0, 4])
    assert rotation_error_deg(rot_z(7), rot_z(10)) == pytest.approx(3.0)
    assert direction_error_deg(np.array([0, 0, 1.0]), np.array([0, 0, 5.0])) == pytest.approx(0.0, abs=1e-6)
    assert direction_error_deg(np.array([1.0, 0, 0]), np.array([0, 0, 2.0])) == pytest.approx(90.0)
    assert direction_error_deg(np.array([1.0, 0, 0]), np.zeros(3)) is None
    assert pair_starts(12, 5, None) == list(range(7)) and pair_starts(12, 1, 3) == [0, 5, 10]
    s = summarise([{"k": 1, "rotation_deg": [1.0, 180.0, 2.0], "translation_deg": [10.0, 180.0, None],
                    "inliers": [40, 0, 30], "success": [True, False, True]}])
    assert s["success_rate"] == pytest.approx(2 / 3) and s["median_rotation_error_deg"] == 2.0
    assert s["median_translation_error_deg"] == pytest.approx(95.0) and s["median_inliers"] == 30


@pytest.mark.usefixtures("one_torch_thread")
def test_ceiling_recovers_rotation_and_floor_fails(tmp_path_factory):
    sc = Scene.load(scene_dir(tmp_path_factory.getbasetemp(), 11))
    caster = RayCaster(sc)
    traj = make_trajectory(caster, 12, 128, 256, 75.0, seed=3)
    gbs = [caster.render(c) for c in traj.cameras]
    anchors = Anchors(sc, seed=0, pool=6)  # > 5: no two frames of a pair share an appearance
    poses, K = [g.world_to_camera for g in gbs], gbs[0].K
    orb = odometry_orb(orb_settings_for(256))
    ceiling = odometry([anchors.ceiling(g, t) for t, g in enumerate(gbs)], poses, K, (1, 5), orb)
    floor = odometry([anchors.floor(g, t) for t, g in enumerate(gbs)], poses, K, (1, 5), orb)
    c1, c5 = summarise([ceiling["1"]]), summarise([ceiling["5"]])
    f1, f5 = summarise([floor["1"]]), summarise([floor["5"]])
    assert c1["pairs"] == 11 and c5["pairs"] == 7
    # the perfect video: rotation within 3 degrees (median), most pairs a success (< 5 degrees)
    assert c5["success_rate"] >= 0.8 and c5["median_rotation_error_deg"] < 3.0, c5
    assert c1["success_rate"] >= 0.6 and c1["median_rotation_error_deg"] < 3.0, c1
    # new detail every frame: far fewer poses recovered
    assert f5["success_rate"] <= c5["success_rate"] - 0.5 and f1["success_rate"] < c1["success_rate"], (f1, f5)
