# A new system from H alone: a particle in a double well, H = p²/2 + (q² − 1)²/4.
import torch

from hnn_pl.systems.base import HamiltonianSystem


class DoubleWell(HamiltonianSystem):
    dof = 1

    def hamiltonian(self, y):
        q, p = y[..., 0], y[..., 1]
        return p**2 / 2 + (q**2 - 1) ** 2 / 4

    def sample_initial(self, n, generator):
        return (torch.rand(n, 2, generator=generator, dtype=torch.float64) * 2 - 1) * 1.5
