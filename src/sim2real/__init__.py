"""sim2real: long-term consistent laparoscopic video from simulated surgical 3D scenes."""

__version__ = "0.1.0"
