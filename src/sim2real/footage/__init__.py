"""Real footage as the target domain: ``sim2real realset`` turns the user's videos and folders of
frames into a real set that training and evaluation read (docs/footage.md).

- :mod:`~sim2real.footage.decode`: sources (videos through PyAV, frame folders through PIL), sampling
- :mod:`~sim2real.footage.content`: the content area (field of view, overlays) as a mask and a box
- :mod:`~sim2real.footage.filters`: dark, overexposed and near-duplicate frames
- :mod:`~sim2real.footage.labels`: class-id masks mapped onto the project's classes
- :mod:`~sim2real.footage.build`: the command's pipeline (temporary folder, then rename)

The real set's layout and manifest, which training reads too, are :mod:`sim2real.data.real_manifest`.
"""
