"""Ideal mass-spring (paper task 1)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hnn_pl.systems.base import HamiltonianSystem, sample_annulus


class MassSpring(HamiltonianSystem):
    """``H = α q² + β p²`` (``α = k/2``, ``β = 1/2m``).

    The defaults ``α = β = 1`` are the reference code's ``H = q² + p²`` (``k = 2``,
    ``m = 1/2``, angular frequency ``ω = 2√(αβ) = 2``); the paper's text states
    ``k = m = 1``, i.e. ``α = β = 1/2``. Initial states as the reference: a uniform
    direction in the (q, p) plane and a radius ``r ~ U[r_min, r_max]``.

    Args:
        alpha, beta: coefficients of ``q²`` and ``p²``.
        radius: ``(r_min, r_max)`` of the initial states' radius.
    """

    dof = 1

    def __init__(
        self, alpha: float = 1.0, beta: float = 1.0, radius: tuple[float, float] = (0.1, 1.0)
    ) -> None:
        self.alpha, self.beta, self.radius = alpha, beta, tuple(radius)

    def hamiltonian(self, y: Tensor) -> Tensor:
        q, p = y.unbind(-1)
        return self.alpha * q**2 + self.beta * p**2

    def vector_field(self, t, y: Tensor) -> Tensor:
        """``(dq/dt, dp/dt) = (2βp, −2αq)``."""
        q, p = y.unbind(-1)
        return torch.stack([2 * self.beta * p, -2 * self.alpha * q], dim=-1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        return sample_annulus(n, self.radius, generator)

    def momentum_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """``p = q̇ / (2β)``, shape ``(..., 1) -> (..., 1)``."""
        return v / (2 * self.beta)

    def exact_solution(self, t: Tensor, y0: Tensor) -> Tensor:
        """Rotation in phase space: with ``ω = 2√(αβ)`` and ``s = √(α/β)``,
        ``q = q₀ cos ωt + p₀/s sin ωt``, ``p = p₀ cos ωt − s q₀ sin ωt``."""
        w, s = 2 * math.sqrt(self.alpha * self.beta), math.sqrt(self.alpha / self.beta)
        c, sn = torch.cos(w * t)[:, None], torch.sin(w * t)[:, None]
        q0, p0 = y0[..., 0], y0[..., 1]
        return torch.stack([q0 * c + p0 / s * sn, p0 * c - s * q0 * sn], dim=-1)
