"""Translator (MUNIT without styles) and multi-scale discriminators."""

from sim2real.models.discriminator import MsImageDis
from sim2real.models.translator import Decoder, Encoder, Translator

__all__ = ["Decoder", "Encoder", "MsImageDis", "Translator"]
