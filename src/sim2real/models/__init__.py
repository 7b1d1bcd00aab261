"""Translator (MUNIT without styles) and multi-scale discriminators."""

from sim2real.models.discriminator import MsImageDis
from sim2real.models.translator import Decoder, Encoder, Models, Translator, build_models

__all__ = ["Decoder", "Encoder", "Models", "MsImageDis", "Translator", "build_models"]
