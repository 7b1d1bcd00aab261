"""Light constants of scenes that the command line needs before it imports trimesh."""

UNITS: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
"""Millimetres per unit of an imported mesh file (scenes store millimetres)."""
ANTERIOR = (0.0, 0.0, 1.0)
"""Default world direction towards the patient's front (the procedural scenes' +z)."""
DEFAULT_CREASE_DEG = 60.0
"""Edges whose faces meet at a larger angle stay sharp when smooth normals are made at import."""
