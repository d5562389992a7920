"""Plain ``nn.Module``s: the MLP, the vector fields built on it, the pixel autoencoder."""

from hnn_pl.nets.autoencoder import PixelDecoder, PixelEncoder
from hnn_pl.nets.fields import DirectField, DissipativeField, HamiltonianField
from hnn_pl.nets.mlp import MLP

__all__ = ["MLP", "DirectField", "HamiltonianField", "DissipativeField"]
__all__ += ["PixelEncoder", "PixelDecoder"]
