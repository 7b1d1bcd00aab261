"""Light constants of scenes that the command line needs before it imports trimesh."""

UNITS: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
"""Millimetres per unit of an imported mesh file (scenes store millimetres)."""
ANTERIOR = (0.0, 0.0, 1.0)
"""Default world direction towards the patient's front (the procedural scenes' +z)."""
DEFAULT_CREASE_DEG = 60.0
"""Edges whose faces meet at a larger angle stay sharp when smooth normals are made at import."""
DEFAULT_FLOW_BUDGET = 0.003
"""Median ground-truth flow per frame, as a fraction of the image width, of :func:`make_trajectory`'s
default path: about 1.5 px per frame at 512 px, so that a perfect video keeps ORB-10 accuracy high
(the paper's slow pans; measured in tests/test_calibration.py and docs/evaluation.md)."""
DEFAULT_MAX_DEG_PER_FRAME = 0.4
"""Bound on the camera's rotation between consecutive frames (degrees)."""
LOOKS = ("smooth", "swing")
"""How a generated test path looks at the scene: a smooth look-at, or swings between liver points."""
CAMERA_AXES = ("opencv", "opengl")
"""Camera axes a pose file may use (:data:`sim2real.scene.pose_import.AXES`): OpenCV's (x right,
y down, looking along +z: TUM's, COLMAP's, sim2real's) or OpenGL's (y up, looking along -z: Blender's)."""
