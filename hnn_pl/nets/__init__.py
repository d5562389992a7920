"""Plain ``nn.Module``s: the MLP, the vector fields built on it, the pixel autoencoder."""

from hnn_pl.nets.autoencoder import PixelDecoder, PixelEncoder
from hnn_pl.nets.fields import DirectField, HamiltonianField
from hnn_pl.nets.mlp import MLP

__all__ = ["MLP", "DirectField", "HamiltonianField", "PixelEncoder", "PixelDecoder"]
