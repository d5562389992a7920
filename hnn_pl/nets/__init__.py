"""Plain ``nn.Module``s: the MLP, the vector fields built on it, the pixel autoencoder."""

from hnn_pl.nets.autoencoder import PixelDecoder, PixelEncoder
from hnn_pl.nets.fields import DirectField, DissipativeField, HamiltonianField
from hnn_pl.nets.lagrangian import (
    CholeskyMass,
    LagrangianField,
    MechanicalHamiltonianField,
    MechanicalLagrangianField,
    MechanicalNets,
)
from hnn_pl.nets.mlp import MLP

__all__ = ["MLP", "DirectField", "HamiltonianField", "DissipativeField"]
__all__ += ["LagrangianField", "MechanicalHamiltonianField", "MechanicalLagrangianField"]
__all__ += ["MechanicalNets", "CholeskyMass"]
__all__ += ["PixelEncoder", "PixelDecoder"]
