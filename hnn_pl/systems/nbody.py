"""Gravitational n-body problems in the plane (paper task 4 and the three-body task 4b).

State layout (this project's convention, **per body interleaved**)::

    y = cat([q, p], -1),   q = (x_1, y_1, …, x_n, y_n),   p = (px_1, py_1, …, px_n, py_n),

with ``p_i = m_i v_i`` the canonical momentum, so ``q.reshape(..., n, 2)[..., i, :]`` is
body ``i``'s position. The reference (greydanus/hamiltonian-nn) orders by component,
``[qx_1..qx_n, qy_1..qy_n, px_1..px_n, py_1..py_n]``, with velocities as ``p`` (every mass
is 1 there); :func:`to_reference_order` / :func:`from_reference_order` only permute.

Hamiltonian (``G`` and the masses ``m_i`` configurable, defaults 1 as the reference)::

    H(q, p) = Σ_i |p_i|² / (2 m_i)  −  Σ_{i<j} G m_i m_j / |q_i − q_j|

Ground-truth tolerances: the reference's scipy RK45 at ``rtol = 1e-9`` and the default
``atol = 1e-6`` is only ~1e-4 accurate for states of order one; we keep
the base class's ``rtol = atol = 1e-10``. Our dopri5 (the Dormand-Prince pair and RMS
norm of scipy's RK45) against a run at ``1e-13`` on the paper's data sets (seed 0; 1000
two-body orbits, t ∈ [0, 20], 50 points; 5000 three-body orbits, t ∈ [0, 5], 20 points):

===============================  ==================  ==================
max |state error|                two-body            three-body
===============================  ==================  ==================
``rtol = atol = 1e-10``          2e-8 (median 2e-9)  5e-7 (median 2e-9)
reference's 1e-9 / 1e-6          1e-3 (median 1e-4)  2e-2 (median 9e-5)
===============================  ==================  ==================

At ``1e-10`` the relative drift of ``H`` is at most 4e-9 / 6e-9, of the angular momentum
2e-9 / 7e-10, at ~105–135 attempted steps per orbit (0.5 s / 1.4 s on 2 CPU cores;
``1e-12`` would cost ~2.5×). The smallest three-body pair distance over all 5000 orbits
is 0.048 (hardest orbit 498 steps, median 90): the sampler needs no rejection of
near-collisions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from hnn_pl.systems.base import HamiltonianSystem, unit_and_radius


def to_reference_order(y: Tensor) -> Tensor:
    """Per-body ``[x_1, y_1, …, px_1, py_1, …]`` → the reference's
    ``[qx_1..qx_n, qy_1..qy_n, px_1..px_n, py_1..py_n]``; shape ``(..., 4n)`` kept."""
    n = y.shape[-1] // 4
    return y.reshape(*y.shape[:-1], 2, n, 2).transpose(-1, -2).reshape(y.shape)


def from_reference_order(y: Tensor) -> Tensor:
    """Inverse of :func:`to_reference_order`."""
    n = y.shape[-1] // 4
    return y.reshape(*y.shape[:-1], 2, 2, n).transpose(-1, -2).reshape(y.shape)


def rotate2d(v: Tensor, theta: Tensor | float) -> Tensor:
    """Rotate vectors ``v (..., 2)`` counter-clockwise by ``theta`` (broadcast over ``...``)."""
    theta = torch.as_tensor(theta, dtype=v.dtype, device=v.device)
    c, s = torch.cos(theta), torch.sin(theta)
    x, y = v[..., 0], v[..., 1]
    return torch.stack([c * x - s * y, s * x + c * y], dim=-1)


class NBody(HamiltonianSystem):
    """``n`` point masses in 2-D under Newtonian gravity (see the module docstring).

    Initial states (:meth:`sample_initial`), the reference's three-body ``random_config``
    (``experiment-3body/data.py``) for ``n`` equal masses ``m``: body ``k`` at
    ``q_k = R(2πk/n) q_0`` on a circle of radius ``r ~ U[r_min, r_max]``, ``q_0`` along a
    normalised ``U[−1, 1]²`` draw (not uniform in angle; centre of mass exactly 0),
    velocity ``R(π/2) q_k · √(G m S_n / 4) / r^{3/2}`` with
    ``S_n = Σ_{k=1}^{n-1} 1/sin(πk/n)`` (the circular-orbit speed of a regular n-gon;
    ``√(S_3/4) = 3^(-1/4)``, the reference's constant), every velocity component then
    multiplied by ``1 + ν·U(−1, 1)`` independently, and ``p = m v``. All orbits turn
    counter-clockwise; as in the reference, the noise does *not* keep the total momentum
    at zero. The reference's *distribution*, drawn with ``torch``, not numpy's stream.

    Args:
        n_bodies: number of bodies ``n``.
        masses: one mass for all bodies or one per body.
        G: gravitational constant.
        orbit_noise: ``ν`` of the velocity perturbation.
        radius: ``(r_min, r_max)`` of the ring radius.
    """

    def __init__(
        self,
        n_bodies: int = 3,
        masses: float | Sequence[float] = 1.0,
        G: float = 1.0,
        orbit_noise: float = 0.2,
        radius: tuple[float, float] = (0.9, 1.2),
    ) -> None:
        if n_bodies < 2:
            raise ValueError(f"need at least two bodies, got {n_bodies}")
        if isinstance(masses, (int, float)):
            masses = [float(masses)] * n_bodies
        if len(masses) != n_bodies:
            raise ValueError(f"{len(masses)} masses for {n_bodies} bodies")
        self.n_bodies, self.G = n_bodies, float(G)
        self.masses = tuple(float(m) for m in masses)
        self.orbit_noise, self.radius = float(orbit_noise), tuple(radius)
        self.dof = 2 * n_bodies
        i, j = torch.triu_indices(n_bodies, n_bodies, offset=1)
        self._pair_i, self._pair_j = i, j
        m = torch.tensor(self.masses, dtype=torch.float64)
        self._m = m
        self._gmm = self.G * m[i] * m[j]  # (P,)
        # incidence (n, P): force of pair (i, j) on i is +f, on j is −f
        inc = torch.zeros(n_bodies, len(i), dtype=torch.float64)
        inc[i, torch.arange(len(i))] = 1.0
        inc[j, torch.arange(len(i))] = -1.0
        self._inc = inc

    def split(self, y: Tensor) -> tuple[Tensor, Tensor]:
        """``y (..., 4n)`` → positions and momenta, each ``(..., n, 2)``."""
        q, p = y.chunk(2, dim=-1)
        return q.unflatten(-1, (self.n_bodies, 2)), p.unflatten(-1, (self.n_bodies, 2))

    def join(self, q: Tensor, p: Tensor) -> Tensor:
        """Inverse of :meth:`split`."""
        return torch.cat([q.flatten(-2), p.flatten(-2)], dim=-1)

    def _consts(self, y: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        kw = {"dtype": y.dtype, "device": y.device}
        return self._m.to(**kw), self._gmm.to(**kw), self._inc.to(**kw)

    def pair_distances(self, y: Tensor) -> Tensor:
        """``|q_i − q_j|`` for the pairs ``i < j`` (row-major), shape ``(..., n(n−1)/2)``."""
        q, _ = self.split(y)
        return (q[..., self._pair_j, :] - q[..., self._pair_i, :]).norm(dim=-1)

    def hamiltonian(self, y: Tensor) -> Tensor:
        """``Σ |p_i|²/(2 m_i) − Σ_{i<j} G m_i m_j / |q_i − q_j|``, shape ``(...)``."""
        m, gmm, _ = self._consts(y)
        _, p = self.split(y)
        kinetic = (p.square().sum(-1) / (2 * m)).sum(-1)
        potential = -(gmm / self.pair_distances(y)).sum(-1)
        return kinetic + potential

    def vector_field(self, t, y: Tensor) -> Tensor:
        """``dq_i/dt = p_i/m_i``, ``dp_i/dt = Σ_j G m_i m_j (q_j − q_i)/|q_j − q_i|³``."""
        m, gmm, inc = self._consts(y)
        q, p = self.split(y)
        d = q[..., self._pair_j, :] - q[..., self._pair_i, :]  # (..., P, 2), q_j − q_i
        r2 = d.square().sum(-1, keepdim=True)
        f = d * (gmm[:, None] / (r2 * r2.sqrt()))  # force of j on i
        dp = torch.einsum("np,...pc->...nc", inc, f)
        return torch.cat([(p / m[:, None]).flatten(-2), dp.flatten(-2)], dim=-1)

    def momentum(self, y: Tensor) -> Tensor:
        """Total linear momentum ``Σ p_i``, shape ``(..., 2)``."""
        return self.split(y)[1].sum(-2)

    def angular_momentum(self, y: Tensor) -> Tensor:
        """Total angular momentum about the origin ``Σ (x_i py_i − y_i px_i)``, shape ``(...)``."""
        q, p = self.split(y)
        return (q[..., 0] * p[..., 1] - q[..., 1] * p[..., 0]).sum(-1)

    def centre_of_mass(self, y: Tensor) -> Tensor:
        """``Σ m_i q_i / Σ m_i``, shape ``(..., 2)``."""
        m, _, _ = self._consts(y)
        q, _ = self.split(y)
        return (m[:, None] * q).sum(-2) / m.sum()

    def _equal_mass(self) -> float:
        if len(set(self.masses)) != 1:
            raise ValueError("the reference initial-state distribution needs equal masses")
        return self.masses[0]

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        """``n`` states ``(n, 4·n_bodies)`` float64 from the ring distribution (class doc)."""
        m, k = self._equal_mass(), self.n_bodies
        f64 = torch.float64
        u, r = unit_and_radius(n, self.radius, generator)
        q0 = u * r  # (n, 2)
        angles = 2 * math.pi / k * torch.arange(k, dtype=f64)  # (k,)
        q = rotate2d(q0[:, None, :], angles)  # (n, k, 2)
        s_n = sum(1 / math.sin(math.pi * j / k) for j in range(1, k))
        speed = math.sqrt(self.G * m * s_n / 4) / r[:, None] ** 1.5  # (n, 1, 1)
        v = rotate2d(q, math.pi / 2) * speed
        v = v * (
            1 + self.orbit_noise * (2 * torch.rand(n, k, 2, generator=generator, dtype=f64) - 1)
        )
        return self.join(q, m * v)
