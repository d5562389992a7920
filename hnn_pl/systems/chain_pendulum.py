"""Chain pendulum: ``n`` point masses on massless rods, the first hung from a fixed pivot.

Coordinates are the absolute angles ``θ_i`` of the links from the downward vertical, as in
the constrained-HNN benchmark (Finzi et al. 2020): bob ``i`` sits at
``x_i = Σ_{j≤i} l_j (sin θ_j, −cos θ_j)`` (``i = 0`` the link at the pivot). With
``μ_i = Σ_{m≥i} m_m`` (the mass hanging from link ``i``) and
``A_jk = l_j l_k μ_max(j,k)``:

- mass matrix ``M(θ)_jk = A_jk cos(θ_j − θ_k)`` (symmetric positive definite);
- potential ``V(θ) = g Σ_i m_i y_i = −g Σ_j μ_j l_j cos θ_j`` (zero at the pivot's height);
- ``H(θ, p) = ½ pᵀ M(θ)⁻¹ p + V(θ)``, ``L(θ, θ̇) = ½ θ̇ᵀ M(θ) θ̇ − V(θ)``, ``p = M(θ) θ̇``;
- Euler–Lagrange: ``M θ̈ = −S θ̇² − g l ∘ μ ∘ sin θ`` with ``S_jk = A_jk sin(θ_j − θ_k)``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from hnn_pl.systems.base import HamiltonianSystem

#: the range of the reference's masses and lengths, drawn once with NumPy seed 0
REFERENCE_RANGE = (0.6, 1.4)
#: the reference's gravity
REFERENCE_G = 9.81


def reference_parameters(n: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The masses and lengths of the reference's ``ChainPendulum(n)``, pivot first.

    The reference draws ``2n`` values ``0.6 + 0.8 U[0, 1)`` from NumPy's legacy generator
    seeded 0 (``n`` masses, then ``n`` lengths) and hands them to the links from the end
    of each list (``list.pop()``): the link at the pivot gets the last draw of each.
    """
    draws = REFERENCE_RANGE[0] + (REFERENCE_RANGE[1] - REFERENCE_RANGE[0]) * np.random.RandomState(
        0
    ).rand(2 * n)
    masses, lengths = draws[:n][::-1], draws[n:][::-1]
    return tuple(float(m) for m in masses), tuple(float(v) for v in lengths)


class ChainPendulum(HamiltonianSystem):
    """``n`` point masses on rigid massless links in a vertical plane (module docstring).

    The state is ``y = (θ, p)`` of shape ``(..., 2n)``, ``p = M(θ) θ̇``. The vector field,
    ``H``, ``L`` and the energy are closed forms with one batched ``n × n`` solve.
    Initial states: :meth:`sample_initial`, the constrained-HNN benchmark's sampler.

    Args:
        n: number of links (degrees of freedom).
        masses, lengths: per link, pivot first; ``None``: the reference's draw
            (:func:`reference_parameters`, ``U[0.6, 1.4]`` with NumPy seed 0).
        g: gravity.
    """

    def __init__(
        self,
        n: int = 2,
        masses: tuple[float, ...] | None = None,
        lengths: tuple[float, ...] | None = None,
        g: float = REFERENCE_G,
    ) -> None:
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f"n must be an integer >= 1, got {n!r}")
        ref_m, ref_l = reference_parameters(n)
        masses = ref_m if masses is None else tuple(float(m) for m in masses)
        lengths = ref_l if lengths is None else tuple(float(v) for v in lengths)
        for name, values in (("masses", masses), ("lengths", lengths)):
            if len(values) != n or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"{name} must be {n} positive numbers, got {list(values)}")
        if not math.isfinite(g):
            raise ValueError(f"g must be finite, got {g}")
        self.n, self.masses, self.lengths, self.g = n, masses, lengths, float(g)

    @property
    def dof(self) -> int:
        return self.n

    def _constants(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``l (n,)``, ``μ (n,)`` (mass below each link, inclusive) and ``A (n, n)`` in
        ``like``'s dtype and device, built once per pair (every field evaluation needs
        them: rebuilt, they were a third of an integration's time). Built outside
        inference mode, so a pair first met there serves autograd later too."""
        key = (like.dtype, like.device)
        cache = self.__dict__.setdefault("_constants_by", {})
        if key not in cache:
            with torch.inference_mode(False):
                m = torch.tensor(self.masses, dtype=like.dtype, device=like.device)
                l = torch.tensor(self.lengths, dtype=like.dtype, device=like.device)
                mu = m.flip(0).cumsum(0).flip(0)
                idx = torch.arange(self.n, device=like.device)
                mu_max = mu[torch.maximum(idx[:, None], idx[None, :])]
                cache[key] = (l, mu, l[:, None] * l[None, :] * mu_max)
        return cache[key]

    def mass_matrix(self, q: Tensor) -> Tensor:
        """``M(θ)_jk = A_jk cos(θ_j − θ_k)``: ``(..., n) -> (..., n, n)``."""
        _, _, a = self._constants(q)
        return a * torch.cos(q[..., :, None] - q[..., None, :])

    def potential(self, q: Tensor) -> Tensor:
        """``V(θ) = −g Σ_j μ_j l_j cos θ_j``: ``(..., n) -> (...)``."""
        l, mu, _ = self._constants(q)
        return -self.g * (mu * l * torch.cos(q)).sum(-1)

    def _potential_force(self, q: Tensor) -> Tensor:
        """``−∂V/∂θ = −g μ ∘ l ∘ sin θ``: ``(..., n)``."""
        l, mu, _ = self._constants(q)
        return -self.g * mu * l * torch.sin(q)

    def velocity(self, q: Tensor, p: Tensor) -> Tensor:
        """``θ̇ = M(θ)⁻¹ p``: ``(..., n), (..., n) -> (..., n)``."""
        return torch.linalg.solve(self.mass_matrix(q), p.unsqueeze(-1)).squeeze(-1)

    def momentum_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """``p = M(θ) θ̇``: ``(..., n), (..., n) -> (..., n)``."""
        return (self.mass_matrix(q) @ v.unsqueeze(-1)).squeeze(-1)

    def hamiltonian(self, y: Tensor) -> Tensor:
        """``½ pᵀ M⁻¹ p + V``: ``(..., 2n) -> (...)``."""
        q, p = y.chunk(2, dim=-1)
        return 0.5 * (p * self.velocity(q, p)).sum(-1) + self.potential(q)

    def lagrangian(self, q: Tensor, v: Tensor) -> Tensor:
        """``½ θ̇ᵀ M θ̇ − V``: ``(..., n), (..., n) -> (...)``."""
        return 0.5 * (v * self.momentum_qv(q, v)).sum(-1) - self.potential(q)

    def energy_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """``½ θ̇ᵀ M θ̇ + V``: ``(..., n), (..., n) -> (...)``."""
        return 0.5 * (v * self.momentum_qv(q, v)).sum(-1) + self.potential(q)

    def _gyroscopic(self, q: Tensor, v: Tensor) -> Tensor:
        """``(S θ̇²)_j = Σ_k A_jk sin(θ_j − θ_k) θ̇_k²``: ``(..., n)``."""
        _, _, a = self._constants(q)
        s = a * torch.sin(q[..., :, None] - q[..., None, :])
        return (s @ (v * v).unsqueeze(-1)).squeeze(-1)

    def acceleration(self, q: Tensor, v: Tensor) -> Tensor:
        """``θ̈ = M⁻¹ (−S θ̇² − g μ ∘ l ∘ sin θ)``: ``(..., n), (..., n) -> (..., n)``."""
        rhs = -self._gyroscopic(q, v) + self._potential_force(q)
        return torch.linalg.solve(self.mass_matrix(q), rhs.unsqueeze(-1)).squeeze(-1)

    def vector_field(self, t, y: Tensor) -> Tensor:
        """``θ̇ = M⁻¹ p``, ``ṗ_j = −θ̇_j (S θ̇)_j − g μ_j l_j sin θ_j``: ``(..., 2n)``."""
        q, p = y.chunk(2, dim=-1)
        v = self.velocity(q, p)
        _, _, a = self._constants(q)
        s = a * torch.sin(q[..., :, None] - q[..., None, :])
        dp = -v * (s @ v.unsqueeze(-1)).squeeze(-1) + self._potential_force(q)
        return torch.cat([v, dp], -1)

    def cartesian(self, q: Tensor) -> Tensor:
        """Bob positions ``x_i = Σ_{j≤i} l_j (sin θ_j, −cos θ_j)``: ``(..., n) -> (..., n, 2)``."""
        l, _, _ = self._constants(q)
        links = l[:, None] * torch.stack([torch.sin(q), -torch.cos(q)], -1)
        return links.cumsum(-2)

    def cartesian_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """Bob positions and velocities ``z = (x, ẋ)``: ``(..., n), (..., n) -> (..., 2, n, 2)``,
        ``ẋ_i = Σ_{j≤i} l_j θ̇_j (cos θ_j, sin θ_j)`` (the reference's Cartesian state)."""
        l, _, _ = self._constants(q)
        links = l[:, None] * torch.stack([torch.sin(q), -torch.cos(q)], -1)
        rates = (l * v)[..., None] * torch.stack([torch.cos(q), torch.sin(q)], -1)
        return torch.stack([links.cumsum(-2), rates.cumsum(-2)], -3)

    def angles_qv(self, z: Tensor) -> tuple[Tensor, Tensor]:
        """The inverse of :meth:`cartesian_qv` on the constraint set: ``θ_i = atan2(d_x,
        −d_y)`` and ``θ̇_i = (d × ḋ) / |d|²`` of each link ``d = x_i − x_{i−1}`` (``x_{−1}``
        the pivot): ``(..., 2, n, 2) -> (..., n), (..., n)``."""
        x, xdot = z.unbind(-3)
        d = torch.diff(x, dim=-2, prepend=torch.zeros_like(x[..., :1, :]))
        dd = torch.diff(xdot, dim=-2, prepend=torch.zeros_like(xdot[..., :1, :]))
        q = torch.atan2(d[..., 0], -d[..., 1])
        v = (d[..., 0] * dd[..., 1] - d[..., 1] * dd[..., 0]) / (d * d).sum(-1)
        return q, v

    def constraints(self, z: Tensor) -> Tensor:
        """The reference's constraints of a Cartesian state ``z = (x, ẋ) (..., 2, n, 2)``:
        ``|d_i|² − l_i²`` and ``2 d_i · ḋ_i`` per link ``d_i = x_i − x_{i−1}``: ``(..., 2n)``."""
        l, _, _ = self._constants(z)
        x, xdot = z.unbind(-3)
        d = torch.diff(x, dim=-2, prepend=torch.zeros_like(x[..., :1, :]))
        dd = torch.diff(xdot, dim=-2, prepend=torch.zeros_like(xdot[..., :1, :]))
        return torch.cat([(d * d).sum(-1) - l**2, 2 * (d * dd).sum(-1)], -1)

    def constraints_jacobian(self, z: Tensor) -> Tensor:
        """``∂Φ/∂z`` of :meth:`constraints` at ``z (B, 2, n, 2)``: ``(B, 2n, 4n)`` (``z``
        flattened). With ``D`` the link-difference matrix (``d = D x``):
        ``∂|d_i|²/∂x_j = 2 d_i D_ij``, ``∂(2 d_i·ḋ_i)/∂x_j = 2 ḋ_i D_ij`` and
        ``∂(2 d_i·ḋ_i)/∂ẋ_j = 2 d_i D_ij``."""
        B, n = z.shape[0], self.n
        eye = torch.eye(n, dtype=z.dtype, device=z.device)
        diff = eye - torch.diag(torch.ones(n - 1, dtype=z.dtype, device=z.device), -1)
        x, xdot = z.unbind(-3)
        d, dd = diff @ x, diff @ xdot
        j = z.new_zeros(B, 2 * n, 2, n, 2)
        j[:, :n, 0] = 2 * d[:, :, None, :] * diff[None, :, :, None]
        j[:, n:, 0] = 2 * dd[:, :, None, :] * diff[None, :, :, None]
        j[:, n:, 1] = 2 * d[:, :, None, :] * diff[None, :, :, None]
        return j.reshape(B, 2 * n, 4 * n)

    def project(self, z: Tensor, tol: float = 1e-12, max_iters: int = 100) -> Tensor:
        """The nearest point of the constraint set by the reference's Newton–Raphson:
        ``z ← z + clamp(−J⁺ Φ(z), ±s/2)`` with ``J = ∂Φ/∂z``, ``J⁺ = Jᵀ(JJᵀ)⁻¹`` (the
        minimum-norm step) and ``s`` the RMS of the batch's ``z``, until the RMS of ``Φ``
        over the batch is ``≤ tol``. ``z (B, 2, n, 2)`` float64 -> ``(B, 2, n, 2)``.

        Raises:
            RuntimeError: not converged in ``max_iters`` iterations.
        """
        z = z.clone()
        for _ in range(max_iters):
            phi = self.constraints(z)
            if float(phi.pow(2).mean().sqrt()) <= tol:
                return z
            j = self.constraints_jacobian(z)
            step = j.transpose(1, 2) @ torch.linalg.solve(j @ j.transpose(1, 2), -phi[..., None])
            scale = float(z.pow(2).mean().sqrt())
            z = z + step.reshape(z.shape).clamp(-scale / 2, scale / 2)
        raise RuntimeError(f"constraint projection did not converge in {max_iters} iterations")

    def from_cartesian(self, z: Tensor) -> Tensor:
        """Cartesian states ``(B, 2, n, 2)`` (projected first) as ``(θ, p) (B, 2n)``."""
        q, v = self.angles_qv(self.project(z))
        return torch.cat([q, self.momentum_qv(q, v)], -1)

    def sample_qv(self, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """The benchmark's starts as ``(θ, θ̇)``, float64 ``(n, k)`` each (see
        :meth:`sample_initial`)."""
        k = self.n
        a = torch.randn(n, 2, k, generator=generator, dtype=torch.float32).double()
        b = torch.randn(n, k, 2, generator=generator, dtype=torch.float32).double()
        c = torch.randn(n, k, 2, generator=generator, dtype=torch.float32).double()
        z = self.cartesian_qv(a[:, 0], a[:, 1])
        x, xdot = z[:, 0] + 0.2 * b, (0.5 * z[:, 1] + 0.4 * c) * 3
        return self.angles_qv(self.project(torch.stack([x, xdot], 1)))

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        """The constrained-HNN benchmark's starts, ``(θ, p)`` float64 ``(n, 2k)``.

        Its draws, in its order and dtype (float32 normals, so the same seed gives the same
        draws as its ``torch.manual_seed``): angles and rates ``θ, θ̇ ~ N(0, 1)``
        ``(n, 2, k)``, mapped to Cartesian ``(x, ẋ)``; then ``x += 0.2 N(0, 1)`` and
        ``ẋ = 3 (0.5 ẋ + 0.4 N(0, 1))`` (each ``(n, k, 2)``), which leaves the constraint
        set; :meth:`project` returns to it and the angles are read back (the reference
        stops its projection at an RMS violation of 1e-5; this one converges).
        """
        q, v = self.sample_qv(n, generator)
        return torch.cat([q, self.momentum_qv(q, v)], -1)


class DoublePendulum(ChainPendulum):
    """:class:`ChainPendulum` with two links: ``M = [[(m₁+m₂) l₁², m₂ l₁ l₂ cos(θ₁−θ₂)],
    [m₂ l₁ l₂ cos(θ₁−θ₂), m₂ l₂²]]``, ``V = −(m₁+m₂) g l₁ cos θ₁ − m₂ g l₂ cos θ₂``."""

    def __init__(
        self,
        masses: tuple[float, float] | None = None,
        lengths: tuple[float, float] | None = None,
        g: float = REFERENCE_G,
    ) -> None:
        super().__init__(2, masses, lengths, g)


class VelocityChart(HamiltonianSystem):
    """A :class:`ChainPendulum` (any system with ``acceleration``, ``velocity`` and
    ``momentum_qv``) read in ``y = (q, q̇)`` instead of ``(q, p)``.

    What the data serve with ``coordinates="velocity"``. Not canonical: the field is
    ``(q̇, q̈(q, q̇))``, not ``J∇H``; :meth:`hamiltonian` is the energy in these
    coordinates (the conserved quantity), and the "momentum" whose velocity is ``v`` is
    ``v`` itself. The truth is the wrapped system's, converted.
    """

    def __init__(self, system: ChainPendulum) -> None:
        self._system = system

    @property
    def canonical(self) -> ChainPendulum:
        """The wrapped system, in ``(q, p)``."""
        return self._system

    @property
    def dof(self) -> int:
        return self._system.dof

    @property
    def rtol(self) -> float:
        return self._system.rtol

    @property
    def atol(self) -> float:
        return self._system.atol

    def to_canonical(self, y: Tensor) -> Tensor:
        """``(q, q̇) -> (q, p)``: ``(..., 2k)``."""
        q, v = y.chunk(2, dim=-1)
        return torch.cat([q, self._system.momentum_qv(q, v)], -1)

    def from_canonical(self, y: Tensor) -> Tensor:
        """``(q, p) -> (q, q̇)``: ``(..., 2k)``."""
        q, p = y.chunk(2, dim=-1)
        return torch.cat([q, self._system.velocity(q, p)], -1)

    def hamiltonian(self, y: Tensor) -> Tensor:
        """The energy ``E(q, q̇)``: ``(..., 2k) -> (...)``."""
        q, v = y.chunk(2, dim=-1)
        return self._system.energy_qv(q, v)

    def vector_field(self, t, y: Tensor) -> Tensor:
        """``(q̇, q̈)``: ``(..., 2k) -> (..., 2k)``."""
        q, v = y.chunk(2, dim=-1)
        return torch.cat([v, self._system.acceleration(q, v)], -1)

    def momentum_qv(self, q: Tensor, v: Tensor) -> Tensor:
        return v

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        return self.from_canonical(self._system.sample_initial(n, generator))

    def trajectory(self, y0: Tensor, t: Tensor) -> Tensor:
        """The wrapped system's truth from ``y0 (n, 2k)``, converted: ``(T, n, 2k)``."""
        y = self._system.trajectory(self.to_canonical(y0.to(torch.float64)), t)
        return self.from_canonical(y).to(y0.dtype)
