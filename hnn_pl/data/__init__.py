"""LightningDataModules: one per task, shared by every model of that task."""

from hnn_pl.data.base import TensorBatches, TrajectoryDataModule
from hnn_pl.data.chain_pendulum import ChainPendulumData
from hnn_pl.data.pixel import PixelPendulumData
from hnn_pl.data.real_pendulum import RealPendulumData
from hnn_pl.data.recording import RecordingData, load_recording
from hnn_pl.data.simulated import SimulatedData

__all__ = [
    "TensorBatches",
    "TrajectoryDataModule",
    "SimulatedData",
    "RealPendulumData",
    "RecordingData",
    "load_recording",
    "PixelPendulumData",
    "ChainPendulumData",
]
