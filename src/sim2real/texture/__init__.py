"""Learnable neural textures and their triplanar projection into pixel space."""

from sim2real.texture.neural_texture import NeuralTexture

__all__ = ["NeuralTexture"]
