"""LightningModules: one model per file."""

from hnn_pl.models.autoencoder_hnn import (
    AutoencoderBaseline,
    AutoencoderDynamicsModel,
    AutoencoderHNN,
)
from hnn_pl.models.base import DynamicsModel
from hnn_pl.models.baseline import Baseline
from hnn_pl.models.dissipative_hnn import DissipativeHNN
from hnn_pl.models.hnn import HNN
from hnn_pl.models.lnn import LNN
from hnn_pl.models.mechanical import MechanicalHNN, MechanicalLNN
from hnn_pl.models.velocity import VelocityModel

__all__ = ["DynamicsModel", "Baseline", "HNN", "DissipativeHNN"]
__all__ += ["LNN", "MechanicalHNN", "MechanicalLNN", "VelocityModel"]
__all__ += ["AutoencoderDynamicsModel", "AutoencoderHNN", "AutoencoderBaseline"]
