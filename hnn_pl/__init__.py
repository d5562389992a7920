"""hnn_pl: Hamiltonian Neural Networks in PyTorch Lightning.

``from hnn_pl import HNN, Baseline, odeint``. Names and submodules
(``hnn_pl.bump.energy_bump``) are imported on first use, so ``import hnn_pl`` (and
``python -m hnn_pl --help``) does not load Lightning.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_LAZY = {
    "odeint": "hnn_pl.integrate",
    "odeint_windows": "hnn_pl.integrate",
    "METHODS": "hnn_pl.integrate",
    "HNN": "hnn_pl.models",
    "Baseline": "hnn_pl.models",
    "DissipativeHNN": "hnn_pl.models",
    "LNN": "hnn_pl.models",
    "MechanicalHNN": "hnn_pl.models",
    "MechanicalLNN": "hnn_pl.models",
    "DynamicsModel": "hnn_pl.models",
    "SimulatedData": "hnn_pl.data",
    "TrajectoryDataModule": "hnn_pl.data",
    "RecordingData": "hnn_pl.data",
    "RolloutCallback": "hnn_pl.callbacks",
    "AutoencoderHNN": "hnn_pl.models",
    "AutoencoderBaseline": "hnn_pl.models",
    "AutoencoderDynamicsModel": "hnn_pl.models",
    "PixelPendulumData": "hnn_pl.data.pixel",
    "PixelRolloutCallback": "hnn_pl.callbacks",
    "RolloutWriter": "hnn_pl.callbacks",
    "rollout": "hnn_pl.evaluation",
    "evaluate": "hnn_pl.evaluation",
    "Rollout": "hnn_pl.evaluation",
    "Protocol": "hnn_pl.evaluation",
    "ReferenceProtocol": "hnn_pl.evaluation",
    "TASKS": "hnn_pl.tasks",
    "HamiltonianSystem": "hnn_pl.systems",
}

#: the submodules reachable as attributes after ``import hnn_pl`` (a fixed list: no
#: name from elsewhere is ever imported)
_SUBMODULES = (
    "bump",
    "callbacks",
    "data",
    "evaluation",
    "integrate",
    "loggers",
    "models",
    "nets",
    "plotting",
    "render",
    "safe_io",
    "systems",
    "tasks",
)

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")  # name is one of _SUBMODULES
    raise AttributeError(f"module 'hnn_pl' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
