"""Evaluation metrics of the paper: realism (FID, KID, Dice) and temporal consistency (OF, ORB-k, revisit).

- :mod:`.inception`: the FID Inception-v3 network, weights from a local file only.
- :mod:`.realism`: FID/KID via torchmetrics, Dice, the labelled ``proxy_*`` stand-in.
- :mod:`.segmenter`: the small liver U-Net behind the Dice metric.
- :mod:`.consistency`: OF error, ORB match accuracy, ORB-k curves.
- :mod:`.revisit`: the revisit protocol (OF and ORB-k on views seen again on the way back).

Torch-heavy submodules are imported here too; import a submodule directly to avoid that.
"""

from sim2real.metrics.consistency import (
    FARNEBACK_PARAMS,
    PAPER_ORB_KS,
    farneback_flow,
    keypoint_pixels,
    match_correctness,
    of_error,
    of_error_sequence,
    orb_accuracy,
    orb_curve,
    orb_matches,
)
from sim2real.metrics.inception import (
    FID_WEIGHTS_ENV,
    FID_WEIGHTS_FILENAME,
    FIDInceptionV3,
    load_fid_inception,
    resolve_fid_weights,
)
from sim2real.metrics.realism import (
    clamp_kid_subset_size,
    dice,
    dice_per_image,
    fid_kid,
    fid_unavailable,
    fid_weights_status,
    proxy_colour_texture_distance,
)
from sim2real.metrics.revisit import revisit_of, revisit_orb, revisit_pairs, view_of_extended
from sim2real.metrics.segmenter import LiverUNet, predict, train_segmenter

__all__ = [
    "FARNEBACK_PARAMS", "PAPER_ORB_KS", "farneback_flow", "keypoint_pixels", "match_correctness", "of_error",
    "of_error_sequence", "orb_accuracy", "orb_curve", "orb_matches", "revisit_of", "revisit_orb",
    "revisit_pairs", "view_of_extended",
    "FID_WEIGHTS_ENV", "FID_WEIGHTS_FILENAME", "FIDInceptionV3", "load_fid_inception", "resolve_fid_weights",
    "clamp_kid_subset_size", "dice", "dice_per_image", "fid_kid", "fid_unavailable", "fid_weights_status",
    "proxy_colour_texture_distance",
    "LiverUNet", "predict", "train_segmenter",
]
