"""Physical systems: one per file, each with its Hamiltonian in the docstring."""

from hnn_pl.systems.base import HamiltonianSystem, symplectic_gradient, system_spec
from hnn_pl.systems.chain_pendulum import ChainPendulum, DoublePendulum, VelocityChart
from hnn_pl.systems.mass_spring import MassSpring
from hnn_pl.systems.nbody import NBody
from hnn_pl.systems.pendulum import Pendulum
from hnn_pl.systems.three_body import ThreeBody
from hnn_pl.systems.two_body import TwoBody

__all__ = [
    "HamiltonianSystem",
    "symplectic_gradient",
    "system_spec",
    "MassSpring",
    "Pendulum",
    "NBody",
    "TwoBody",
    "ThreeBody",
    "ChainPendulum",
    "DoublePendulum",
    "VelocityChart",
]
