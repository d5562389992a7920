"""Ideal pendulum (paper task 2), and the energy form shared by the measured ones."""

from __future__ import annotations

import torch
from torch import Tensor

from hnn_pl.systems.base import HamiltonianSystem, sample_annulus


class Pendulum(HamiltonianSystem):
    """``H = α (1 − cos q) + β p²`` (``α = mgl``, ``β = 1/(2ml²)``).

    The defaults ``α = 3, β = 1`` are the reference code's ``H = 3(1 − cos q) + p²``;
    the paper's text states ``2mgl(1 − cos q) + l²p²/2m`` with ``m = l = 1, g = 3``.
    Initial states: uniform direction, radius ``U[1.3, 2.3]`` as the reference.

    Args:
        alpha, beta: coefficients of ``1 − cos q`` and ``p²``.
        radius: ``(r_min, r_max)`` of the initial states' radius in the (q, p) plane.
    """

    dof = 1

    def __init__(
        self, alpha: float = 3.0, beta: float = 1.0, radius: tuple[float, float] = (1.3, 2.3)
    ) -> None:
        self.alpha, self.beta, self.radius = alpha, beta, tuple(radius)

    def hamiltonian(self, y: Tensor) -> Tensor:
        q, p = y.unbind(-1)
        return self.alpha * (1 - torch.cos(q)) + self.beta * p**2

    def vector_field(self, t, y: Tensor) -> Tensor:
        """``(dq/dt, dp/dt) = (2βp, −α sin q)``."""
        q, p = y.unbind(-1)
        return torch.stack([2 * self.beta * p, -self.alpha * torch.sin(q)], dim=-1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        return sample_annulus(n, self.radius, generator)

    def momentum_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """``p = q̇ / (2β)``, shape ``(..., 1) -> (..., 1)``."""
        return v / (2 * self.beta)
