"""Losses of the paper: LSGAN, L1 reconstructions, grey MS-SSIM (or edge recall), view consistency."""

from sim2real.losses.consistency import angle_loss, masked_l1_loss, view_consistency, warp_backward
from sim2real.losses.gan import lsgan_dis_loss, lsgan_gen_loss
from sim2real.losses.reconstruction import l1
from sim2real.losses.ssim import check_ssim_size, grey, ms_ssim_loss
from sim2real.losses.structure import edge_recall_loss, structure_ab_loss

__all__ = [
    "angle_loss", "check_ssim_size", "edge_recall_loss", "grey", "l1", "lsgan_dis_loss", "lsgan_gen_loss",
    "masked_l1_loss", "ms_ssim_loss", "structure_ab_loss", "view_consistency", "warp_backward",
]
