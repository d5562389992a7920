"""Lagrangian and mass-matrix-structured fields: the Euler–Lagrange solve of a learned
``L_θ(q, q̇)`` (LNN), and a learned ``M_θ(q)``, ``V_θ(q)`` in Hamiltonian or Lagrangian form.

The routines take any callables (``L(q, q̇)``, ``M(q)``, ``V(q)`` on batches whose rows
are independent), so an exact Lagrangian plugs in where a network does. States on the
last axis: ``y = (q, p)`` for a Hamiltonian field, ``x = (q, q̇)`` for a Lagrangian one,
each ``(B, 2k)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import torch
from torch import Tensor, nn
from torch.func import grad, jvp, vjp, vmap

#: a singular velocity Hessian is refused (``"raise"``) or solved with a ridge (``"ridge"``)
ON_SINGULAR = ("ridge", "raise")

Lagrangian = Callable[[Tensor, Tensor], Tensor]


def spd_solve(m: Tensor, b: Tensor) -> Tensor:
    """``m⁻¹ b`` for symmetric positive definite ``m (…, k, k)`` and ``b (…, k)`` by a
    Cholesky solve; a row whose ``m`` is not positive definite (non-finite entries) gives
    ``NaN`` rather than an exception, so the integrator reports it as a diverged row."""
    factor, info = torch.linalg.cholesky_ex(m)
    x = torch.cholesky_solve(b[..., None], factor)[..., 0]
    return torch.where((info == 0)[..., None], x, torch.full_like(x, float("nan")))


def spd_inverse(m: Tensor) -> Tensor:
    """``m⁻¹`` of symmetric positive definite ``m (…, k, k)`` by a Cholesky solve against
    ``I`` (not ``torch.cholesky_inverse``, whose forward-mode derivative is wrong in
    torch 2.13: a Jacobian–vector product through it is off by O(1))."""
    eye = torch.eye(m.shape[-1], dtype=m.dtype, device=m.device).expand_as(m)
    return torch.cholesky_solve(eye, torch.linalg.cholesky(m))


class Accelerations(NamedTuple):
    """``q̈ (B, k)`` and ``singular (B,)``: the rows whose velocity Hessian was singular or
    ill-conditioned (their ``q̈`` is the ridge-regularised solve)."""

    acceleration: Tensor
    singular: Tensor


class LagrangianTerms(NamedTuple):
    """What the Euler–Lagrange equations need of ``L`` at ``(q, q̇)``, each per row:
    ``dl_dq (B, k)``, ``dl_dv (B, k)`` (the momenta ``∂L/∂q̇``), ``hess_vv (B, k, k)``
    (``∂²L/∂q̇²``) and ``mixed (B, k)`` (``(∂²L/∂q̇∂q) q̇``)."""

    dl_dq: Tensor
    dl_dv: Tensor
    hess_vv: Tensor
    mixed: Tensor


def lagrangian_terms(lagrangian: Lagrangian, q: Tensor, v: Tensor) -> LagrangianTerms:
    """:class:`LagrangianTerms` of ``lagrangian: (q (B, k), q̇ (B, k)) -> (B,)`` by
    forward-over-reverse (``torch.func``): the gradient of ``Σ_b L`` gives every row's
    ``(∂L/∂q, ∂L/∂q̇)``; ``k + 1`` directional derivatives of it, vmapped over the
    directions (not the samples) — ``(0, e_i)`` for the rows of ``∂²L/∂q̇²`` and
    ``(q̇, 0)`` for ``(∂²L/∂q̇∂q) q̇`` — give the only Hessian blocks the solve uses.
    Differentiable (a loss on the result back-propagates to ``L``'s parameters)."""
    k = q.shape[-1]
    gradient = grad(lambda a, b: lagrangian(a, b).sum(), argnums=(0, 1))
    eye = torch.eye(k, dtype=q.dtype, device=q.device)
    tq = torch.cat([torch.zeros(k, *q.shape, dtype=q.dtype, device=q.device), v[None]])
    tv = torch.cat([eye[:, None, :].expand(k, *v.shape), torch.zeros_like(v)[None]])

    def along(dq: Tensor, dv: Tensor) -> tuple[tuple[Tensor, Tensor], tuple[Tensor, Tensor]]:
        return jvp(gradient, (q, v), (dq, dv))

    (dl_dq, dl_dv), (_, d_dv) = vmap(along)(tq, tv)
    hess_vv = d_dv[:k].permute(1, 0, 2)  # (B, i, j) = ∂²L/∂q̇_j∂q̇_i
    return LagrangianTerms(dl_dq[0], dl_dv[0], hess_vv, d_dv[k])


def lagrangian_terms_autograd(lagrangian: Lagrangian, q: Tensor, v: Tensor) -> LagrangianTerms:
    """:func:`lagrangian_terms` by double autograd (``k + 2`` backward passes, a Python
    loop over the ``k`` degrees of freedom, none over samples): the same numbers, kept to
    compare costs (``benchmarks/lagrangian_step.py``)."""
    record = torch.is_grad_enabled()

    def grad_v(out: Tensor) -> Tensor:
        (g,) = torch.autograd.grad(out.sum(), v, create_graph=True, allow_unused=True)
        return torch.zeros_like(v) if g is None else g

    with torch.enable_grad():
        q = q if q.requires_grad else q.detach().requires_grad_(True)
        v = v if v.requires_grad else v.detach().requires_grad_(True)
        dl_dq, dl_dv = torch.autograd.grad(lagrangian(q, v).sum(), (q, v), create_graph=True)
        rows = [grad_v(dl_dv[:, i]) for i in range(q.shape[-1])]
        mixed = grad_v(dl_dq * v.detach())
    terms = LagrangianTerms(dl_dq, dl_dv, torch.stack(rows, 1), mixed)
    return terms if record else LagrangianTerms(*(t.detach() for t in terms))


def mlp_lagrangian_terms(net: nn.Module, q: Tensor, v: Tensor) -> LagrangianTerms:
    """:func:`lagrangian_terms` of ``L = net(cat(q, q̇))[..., 0]`` for a ``tanh``
    :class:`~hnn_pl.nets.MLP`, in closed form (plain matrix products; a loss on it needs
    one ordinary backward pass).

    With ``a_l = W_l h_{l−1} + b_l``, ``h_l = tanh a_l``, ``r_l = ∂L/∂h_l`` (backward pass)
    and ``J_l = ∂a_l/∂x``, the input Hessian is exactly
    ``∇²L = Σ_l J_lᵀ diag(σ''(a_l) ⊙ r_l) J_l`` (affine maps have no curvature). Only its
    products with the ``k + 1`` directions ``U = [(0, e_1) … (0, e_k), (q̇, 0)]`` are
    needed, so ``J_l U (B, k+1, h)`` is carried forward: ``k + 1`` extra products per
    layer instead of ``2k`` for the full Hessian, and no backward pass of tangents.

    With the MLP's ``angles`` (indices of ``q`` only) ``U`` enters through the features'
    Jacobian; their own curvature acts on the ``q``–``q`` block alone, which the
    Euler–Lagrange solve does not use."""
    k = q.shape[-1]
    x = torch.cat([q, v], -1)
    if any(i >= k for i in getattr(net, "angles", ())):
        raise ValueError(f"angles must index q (< {k}) in an LNN: {list(net.angles)}")
    hs = net.activations(x)
    r = net.out.weight[0].expand_as(hs[-1])
    rs = [r]
    for i in range(len(hs) - 1, 0, -1):
        r = (r * (1 - hs[i] ** 2)) @ net.hidden[i].weight
        rs.append(r)
    rs.reverse()
    w1 = net.hidden[0].weight
    grad_x = (rs[0] * (1 - hs[0] ** 2)) @ w1
    if getattr(net, "angles", ()):
        grad_x = net.features_vjp(x, grad_x)
        eye = torch.eye(k, dtype=x.dtype, device=x.device)
        dirs = torch.cat([torch.zeros(k, k, dtype=x.dtype, device=x.device), eye], -1)
        dirs = torch.cat([dirs.expand(len(x), k, 2 * k), torch.cat([v, 0 * v], -1)[:, None]], 1)
        t = net.features_jvp(x[:, None], dirs) @ w1.T
    else:
        t = torch.cat([w1[:, k:].T.expand(q.shape[0], k, -1), (v @ w1[:, :k].T)[:, None]], 1)
    hess = 0.0
    for i, (h, r) in enumerate(zip(hs, rs)):
        slope = 1 - h**2
        curvature = -2 * h * slope * r
        hess = hess + ((t[:, :k, None] * curvature[:, None, None]) * t[:, None]).sum(-1)
        if i + 1 < len(hs):
            t = (t * slope[:, None]) @ net.hidden[i + 1].weight.T
    return LagrangianTerms(grad_x[:, :k], grad_x[:, k:], hess[..., :k], hess[..., k])


def guarded_solve(
    a: Tensor, b: Tensor, rcond: float = 1e-6, ridge: float = 1e-3, on_singular: str = "ridge"
) -> Accelerations:
    """``x (B, k)`` with ``a x = b`` for symmetric ``a (B, k, k)``, ``b (B, k)``, and the
    rows where ``a`` is singular or ill-conditioned: ``min|λ| ≤ rcond · max|λ|`` over its
    eigenvalues ``λ``, or not finite. Those rows are solved with
    ``a + ridge · max(max|λ|, 1) · I`` instead (``on_singular="ridge"``: finite, flagged)
    or refused with a one-line ``FloatingPointError`` (``"raise"``)."""
    if on_singular not in ON_SINGULAR:
        raise ValueError(f"on_singular must be one of {ON_SINGULAR}: {on_singular!r}")
    with torch.no_grad():
        finite = torch.isfinite(a).flatten(1).all(-1)
        lam = torch.linalg.eigvalsh(torch.where(finite[:, None, None], a, 0.0)).abs()
        top = lam.max(-1).values
        singular = ~finite | (lam.min(-1).values <= rcond * top)
    if bool(singular.any()):
        if on_singular == "raise":
            raise FloatingPointError(
                f"the velocity Hessian ∂²L/∂q̇² is singular or ill-conditioned (min|λ| ≤ "
                f"{rcond:g}·max|λ|) at {int(singular.sum())} of {len(singular)} states: "
                "no unique accelerations there"
            )
        shift = ridge * torch.where(singular, top.clamp(min=1.0), 0.0)
        eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device)
        a = torch.where(finite[:, None, None], a, eye) + shift[:, None, None] * eye
    return Accelerations(torch.linalg.solve(a, b), singular)


def euler_lagrange(
    lagrangian: Lagrangian,
    q: Tensor,
    v: Tensor,
    rcond: float = 1e-6,
    ridge: float = 1e-3,
    on_singular: str = "ridge",
    terms: Callable[[Lagrangian, Tensor, Tensor], LagrangianTerms] = lagrangian_terms,
) -> Accelerations:
    """The accelerations of ``lagrangian`` at ``q, q̇ (B, k)`` by the Euler–Lagrange
    equations, one batched solve: ``∂²L/∂q̇² q̈ = ∂L/∂q − (∂²L/∂q̇∂q) q̇``
    (:func:`lagrangian_terms`, :func:`guarded_solve`)."""
    t = terms(lagrangian, q, v)
    return guarded_solve(t.hess_vv, t.dl_dq - t.mixed, rcond, ridge, on_singular)


def lagrangian_energy(lagrangian: Lagrangian, q: Tensor, v: Tensor) -> Tensor:
    """``E = q̇·∂L/∂q̇ − L``: ``(B, k), (B, k) -> (B,)``, under any grad mode."""
    record = torch.is_grad_enabled() and not torch.is_inference_mode_enabled()
    with torch.inference_mode(False), torch.enable_grad():
        vv = v.clone() if v.requires_grad else v.clone().requires_grad_(True)
        qq = q.clone()
        lag = lagrangian(qq, vv)
        (dl_dv,) = torch.autograd.grad(lag.sum(), vv, create_graph=record)
        e = (v * dl_dv).sum(-1) - lag
    return e if record else e.detach()


# ------------------------------------------------------------------ mass-matrix models

MassMatrix = Callable[[Tensor], Tensor]
Potential = Callable[[Tensor], Tensor]


def potential_grad(potential: Potential, q: Tensor) -> Tensor:
    """``∇V(q) (B, k)`` of ``potential: (B, k) -> (B,)`` (rows independent)."""
    return grad(lambda a: potential(a).sum())(q)


def mass_action(mass: MassMatrix, q: Tensor, c: Tensor) -> Tensor:
    """``M(q) c``: ``(B, k), (B, k) -> (B, k)``."""
    return (mass(q) @ c[..., None])[..., 0]


def mechanical_hamiltonian_field(
    mass: MassMatrix, potential: Potential, q: Tensor, p: Tensor
) -> Tensor:
    """``dy/dt = (∂H/∂p, −∂H/∂q)`` of ``H = ½ pᵀ M(q)⁻¹ p + V(q)``, ``(B, 2k)``.

    With ``u = M⁻¹p`` (Cholesky solve): ``∂H/∂p = u`` and
    ``∂H/∂q = −½ ∂(uᵀ M(q) u)/∂q|_u + ∇V``, one vector–Jacobian product of
    ``q ↦ M(q) u`` (no derivative of the factorisation). ``mass: (B, k) -> (B, k, k)``
    symmetric positive definite, ``potential: (B, k) -> (B,)``."""
    m = mass(q)
    u = spd_solve(m, p)
    _, pull = vjp(lambda a: mass_action(mass, a, u), q)
    (dt_dq,) = pull(0.5 * u)
    return torch.cat([u, dt_dq - potential_grad(potential, q)], -1)


def mechanical_acceleration(mass: MassMatrix, potential: Potential, q: Tensor, v: Tensor) -> Tensor:
    """``q̈ (B, k)`` of ``L = ½ q̇ᵀ M(q) q̇ − V(q)``:
    ``M q̈ = ½ ∂(q̇ᵀ M(q) q̇)/∂q|_q̇ − (Σ_j ∂M/∂q_j q̇_j) q̇ − ∇V``, solved with ``M``'s
    Cholesky factor; the two middle terms are a vector–Jacobian and a Jacobian–vector
    product of ``q ↦ M(q) q̇`` (no Hessian)."""
    m = mass(q)
    _, pull = vjp(lambda a: mass_action(mass, a, v), q)
    (half_grad,) = pull(0.5 * v)
    _, coriolis = jvp(lambda a: mass_action(mass, a, v), (q,), (v,))
    rhs = half_grad - coriolis - potential_grad(potential, q)
    return spd_solve(m, rhs)


class CholeskyMass(nn.Module):
    """``M = L Lᵀ + εI`` from a network's ``k(k+1)/2`` outputs ``raw``: ``L = I + R``,
    ``R`` lower triangular with ``raw`` placed row by row; symmetric positive definite by
    construction, eigenvalues ``≥ ε``, and ``M ≈ (1 + ε) I`` for small outputs.

    The diagonal is ``1 + raw``, not a positive map of ``raw``: ``softplus``'s flat tail is
    an absorbing state (at ``L → 0`` the loss's gradient in ``raw`` vanishes), where a
    step of a high learning rate left the spring's and the pendulum's structured models
    on their fast recipes (3 of 5 seeds each), ``M = εI`` everywhere; ``L``'s sign is free
    instead, and ``L = 0`` is a saddle the optimiser leaves.

    Args:
        dof: ``k``.
        eps: the eigenvalue floor ``ε``.
    """

    def __init__(self, dof: int, eps: float = 1e-3) -> None:
        super().__init__()
        self.dof, self.eps = dof, eps
        rows, cols = torch.tril_indices(dof, dof)
        place = torch.zeros(len(rows), dof * dof)
        place[torch.arange(len(rows)), rows * dof + cols] = 1.0
        self.register_buffer("place", place, persistent=False)
        self.register_buffer("diagonal", rows == cols, persistent=False)

    @property
    def size(self) -> int:
        """``k(k+1)/2``: the outputs a factor takes."""
        return self.dof * (self.dof + 1) // 2

    def lower(self, raw: Tensor) -> Tensor:
        """``L = I + R``: ``(B, k(k+1)/2) -> (B, k, k)``."""
        raw = torch.where(self.diagonal, raw + 1.0, raw)
        return (raw @ self.place.to(raw.dtype)).unflatten(-1, (self.dof, self.dof))

    def forward(self, raw: Tensor) -> Tensor:
        """``M = L Lᵀ + εI``: ``(B, k(k+1)/2) -> (B, k, k)``."""
        return self.from_factor(self.lower(raw))

    def from_factor(self, f: Tensor) -> Tensor:
        """``L Lᵀ + εI``: ``(B, k, k) -> (B, k, k)``."""
        eye = torch.eye(self.dof, dtype=f.dtype, device=f.device)
        return f @ f.transpose(-1, -2) + self.eps * eye

    def raw_grad(self, f: Tensor, u: Tensor) -> Tensor:
        """``∂/∂raw ½ uᵀ M u`` at fixed ``u (B, k)``: ``½|Lᵀu|²``'s gradient in ``L`` is
        ``u (Lᵀu)ᵀ``, read through the placement: ``(B, k(k+1)/2)``."""
        w = (f.transpose(-1, -2) @ u[..., None])[..., 0]
        return (u[:, :, None] * w[:, None, :]).flatten(1) @ self.place.to(u.dtype).T

    def action_tangent(self, f: Tensor, d_raw: Tensor, u: Tensor) -> Tensor:
        """``dM u = dL (Lᵀu) + L (dLᵀu)`` for a tangent ``d_raw`` of ``raw``: ``(B, k)``."""
        df = (d_raw @ self.place.to(u.dtype)).unflatten(-1, (self.dof, self.dof))
        w = (f.transpose(-1, -2) @ u[..., None])[..., 0]
        return (df @ w[..., None] + f @ (df.transpose(-1, -2) @ u[..., None]))[..., 0]


class MechanicalLinearization(NamedTuple):
    """``M_θ``, ``V_θ`` at one batch of ``q (B, k)`` with what their ``q``-derivatives need,
    in closed form (``tanh`` networks): the networks' activations ``hs`` (one list per
    network), the factor ``f`` and the matrix
    ``mass = f fᵀ + εI`` it gives: ``M_θ``, or ``M_θ⁻¹`` for ``nets.inverse``."""

    nets: MechanicalNets
    q: Tensor
    hs: tuple[list[Tensor], ...]
    f: Tensor
    mass: Tensor

    def force(self, u: Tensor, kinetic: float = 1.0) -> Tensor:
        """``c ∂/∂q ½ uᵀ A(q) u − ∇V_θ(q)`` at fixed ``u (B, k)``, ``A = f fᵀ + εI`` the
        factor's matrix and ``c = kinetic``: one closed-form vector–Jacobian product per
        network: ``(B, k)``."""
        g = kinetic * self.nets.cholesky.raw_grad(self.f, u)
        minus_one = -torch.ones_like(g[:, :1])
        q = self.q
        if self.nets.shared:
            return self.nets.net.input_vjp(self.hs[0], torch.cat([g, minus_one], -1), q)
        return self.nets.mass_net.input_vjp(self.hs[0], g, q) + self.nets.potential_net.input_vjp(
            self.hs[1], minus_one, q
        )

    def action_jvp(self, u: Tensor, dq: Tensor) -> Tensor:
        """``d/dε A(q + ε dq) u`` of the factor's matrix ``A``: ``(B, k), (B, k) -> (B, k)``."""
        net = self.nets.net if self.nets.shared else self.nets.mass_net
        d_raw = net.input_jvp(self.hs[0], dq, self.q)[:, : self.nets.cholesky.size]
        return self.nets.cholesky.action_tangent(self.f, d_raw, u)


# ------------------------------------------------------------------ fields


def usable(x: Tensor) -> Tensor:
    """``x``, or a normal copy of an inference-mode tensor, so that ``torch.func`` can
    differentiate through it under ``torch.inference_mode`` (Lightning's evaluation)."""
    if not x.is_inference():
        return x
    with torch.inference_mode(False):
        return x.clone()


class VelocityField(nn.Module):
    """A field whose own states are ``x = (q, q̇)`` (``(B, 2k)``), shown in the data's
    coordinates through an optional ``chart``.

    Subclasses give :meth:`acceleration` and :meth:`energy`. ``native_vector_field`` is
    ``(q̇, q̈)``. With ``chart = None`` the field's ``vector_field``/``hamiltonian`` take
    ``(q, q̇)`` as well; with a chart (an object with ``to_velocity(y)`` and
    ``momentum_rate(y, x, a)``, e.g. :class:`~hnn_pl.models.velocity.VelocityChart` of the
    data's system) they take the data's ``y = (q, p)``: ``dy/dt = (q̇, ṗ)`` with
    ``x = chart.to_velocity(y)`` and ``ṗ`` the system's ``d/dt p(q, q̇)``, and
    ``hamiltonian(y) = E(chart.to_velocity(y))`` — so rollouts, the field error and the
    learned energy compare with every other model's in the data's coordinates. The chart
    is a plain attribute (not saved): the model attaches it from the data.
    """

    chart = None

    def acceleration(self, q: Tensor, v: Tensor) -> Tensor:
        """``q̈_θ(q, q̇)``: ``(B, k), (B, k) -> (B, k)``."""
        raise NotImplementedError

    def energy(self, x: Tensor) -> Tensor:
        """The learned energy ``E_θ(q, q̇)``: ``(B, 2k) -> (B,)``."""
        raise NotImplementedError

    def native_vector_field(self, t: Tensor | float | None, x: Tensor) -> Tensor:
        """``dx/dt = (q̇, q̈_θ(q, q̇))``: ``(B, 2k) -> (B, 2k)``."""
        x = usable(x)
        q, v = x.chunk(2, -1)
        return torch.cat([v, self.acceleration(q, v)], -1)

    def forward(self, y: Tensor) -> Tensor:
        return self.vector_field(None, y)

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """The field in the data's coordinates (``(q, p)`` through the chart, else
        ``(q, q̇)``): ``(B, 2k) -> (B, 2k)``."""
        if self.chart is None:
            return self.native_vector_field(t, y)
        y = usable(y)
        x = self.chart.to_velocity(y).to(y.dtype)
        q, v = x.chunk(2, -1)
        a = self.acceleration(q, v)
        return torch.cat([v, self.chart.momentum_rate(y, x, a).to(y.dtype)], -1)

    def hamiltonian(self, y: Tensor) -> Tensor:
        """The learned energy in the data's coordinates: ``(B, 2k) -> (B,)``."""
        y = usable(y)
        return self.energy(y if self.chart is None else self.chart.to_velocity(y).to(y.dtype))


class LagrangianField(VelocityField):
    """An LNN (Cranmer et al. 2020): a scalar ``L_θ(q, q̇) = net(cat(q, q̇))`` and its
    Euler–Lagrange accelerations (:func:`euler_lagrange`); energy
    ``E_θ = q̇·∂L_θ/∂q̇ − L_θ``.

    ``kinetic_prior = c > 0`` adds ``½ c |q̇|²``: ``L_θ = ½ c|q̇|² + net``, a unit-mass
    kinetic term the network corrects (any ``L`` stays representable); it keeps a
    freshly initialised ``∂²L_θ/∂q̇²`` near ``cI`` instead of a random, often nearly
    singular matrix, whose inverse otherwise throws the first steps' accelerations far
    off. ``c = 0`` is the plain LNN.

    Rows whose ``∂²L_θ/∂q̇²`` is singular or ill-conditioned are counted
    (``singular_rows`` of ``seen_rows`` since :meth:`reset_counts`) and solved with a
    ridge, or refused (``on_singular="raise"``).

    Args:
        net: ``(B, 2k) -> (B, 1)``.
        kinetic_prior: ``c``.
        rcond, ridge, on_singular: the guard of :func:`guarded_solve`.
        terms: how the Hessian blocks are computed from ``(lagrangian, q, q̇)``; ``None``:
            :func:`mlp_lagrangian_terms` for a ``tanh`` MLP, else :func:`lagrangian_terms`.
    """

    def __init__(
        self,
        net: nn.Module,
        kinetic_prior: float = 0.0,
        rcond: float = 1e-6,
        ridge: float = 1e-3,
        on_singular: str = "ridge",
        terms: Callable[[Lagrangian, Tensor, Tensor], LagrangianTerms] | None = None,
    ) -> None:
        super().__init__()
        if on_singular not in ON_SINGULAR:
            raise ValueError(f"on_singular must be one of {ON_SINGULAR}: {on_singular!r}")
        self.net, self.rcond, self.ridge, self.on_singular = net, rcond, ridge, on_singular
        self.kinetic_prior, self.terms = kinetic_prior, terms
        self.reset_counts()

    def reset_counts(self) -> None:
        """Start counting singular rows anew."""
        self.singular_rows, self.seen_rows = torch.zeros(()), 0

    @property
    def singular_fraction(self) -> Tensor:
        """Singular rows over rows solved since :meth:`reset_counts` (0 before any)."""
        return self.singular_rows / max(self.seen_rows, 1)

    def lagrangian(self, q: Tensor, v: Tensor) -> Tensor:
        """``L_θ(q, q̇) = ½ c|q̇|² + net(q, q̇)``: ``(B, k), (B, k) -> (B,)``."""
        out = self.net(torch.cat([q, v], -1))[..., 0]
        return out + 0.5 * self.kinetic_prior * (v**2).sum(-1) if self.kinetic_prior else out

    def hessian_terms(self, q: Tensor, v: Tensor) -> LagrangianTerms:
        """:class:`LagrangianTerms` of ``L_θ`` at ``q, q̇ (B, k)``."""
        if self.terms is not None:
            return self.terms(self.lagrangian, q, v)
        if not (
            getattr(self.net, "activation", None) == "tanh" and hasattr(self.net, "activations")
        ):
            return lagrangian_terms(self.lagrangian, q, v)
        t = mlp_lagrangian_terms(self.net, q, v)
        if not self.kinetic_prior:
            return t
        eye = torch.eye(q.shape[-1], dtype=q.dtype, device=q.device)
        c = self.kinetic_prior
        return t._replace(dl_dv=t.dl_dv + c * v, hess_vv=t.hess_vv + c * eye)

    def acceleration(self, q: Tensor, v: Tensor) -> Tensor:
        q, v = usable(q), usable(v)
        t = self.hessian_terms(q, v)
        out = guarded_solve(t.hess_vv, t.dl_dq - t.mixed, self.rcond, self.ridge, self.on_singular)
        self.singular_rows = self.singular_rows + out.singular.sum().cpu()
        self.seen_rows += len(out.singular)
        return out.acceleration

    def energy(self, x: Tensor) -> Tensor:
        q, v = usable(x).chunk(2, -1)
        return lagrangian_energy(self.lagrangian, q, v)


class MechanicalNets(nn.Module):
    """A learned mass matrix and potential of ``q``: ``M_θ(q)`` from a factor matrix
    ``A = L Lᵀ + εI`` (:class:`CholeskyMass` of ``k(k+1)/2`` network outputs) and
    ``V_θ(q)`` (one output). ``A`` is ``M_θ`` itself, or with ``inverse`` its inverse
    ``M_θ⁻¹`` (the constrained-HNN reference's choice: in ``(q, p)`` the kinetic energy
    ``½ pᵀAp`` and the velocity ``Ap`` need no solve; ``M_θ``'s eigenvalues are then
    ``≤ 1/ε``). ``shared``: one ``MLP(k → h … → k(k+1)/2 + 1)`` whose hidden layers both
    read (as DeLaN's shared trunk; the cost of one network); else two MLPs of that width
    and depth. ``angles``: the coordinates of ``q`` that enter the MLPs as
    ``(cos q_i, sin q_i)`` (:class:`~hnn_pl.nets.MLP`).

    Args:
        dof: ``k``.
        hidden_dim, n_hidden, activation: the MLPs'.
        eps: ``A``'s eigenvalue floor ``ε``.
        shared: one network for both (``True``) or one each.
        angles: indices ``i < k`` of the angles among ``q``.
        inverse: ``A = M_θ⁻¹`` (``True``) or ``A = M_θ``.
        angle_pairs: the angles' pairwise differences and sums as inputs too.
    """

    def __init__(
        self,
        dof: int,
        hidden_dim: int,
        n_hidden: int,
        activation: str,
        eps: float = 1e-3,
        shared: bool = True,
        angles: Sequence[int] = (),
        inverse: bool = False,
        angle_pairs: bool = False,
    ) -> None:
        from hnn_pl.nets.mlp import MLP

        super().__init__()
        self.cholesky, self.shared, self.inverse = CholeskyMass(dof, eps), shared, inverse
        n = self.cholesky.size
        if shared:
            self.net = MLP(dof, n + 1, hidden_dim, n_hidden, activation, angles, angle_pairs)
        else:
            self.mass_net = MLP(dof, n, hidden_dim, n_hidden, activation, angles, angle_pairs)
            self.potential_net = MLP(dof, 1, hidden_dim, n_hidden, activation, angles, angle_pairs)

    def outputs(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """The factor's raw outputs ``(B, k(k+1)/2)`` and ``V_θ(q) (B,)``."""
        if self.shared:
            out = self.net(q)
            return out[..., :-1], out[..., -1]
        return self.mass_net(q), self.potential_net(q)[..., 0]

    def factor_matrix(self, q: Tensor) -> Tensor:
        """``A(q) = L Lᵀ + εI``, ``M_θ`` or (``inverse``) ``M_θ⁻¹``: ``(B, k) -> (B, k, k)``."""
        return self.cholesky(self.outputs(q)[0])

    def mass(self, q: Tensor) -> Tensor:
        """``M_θ(q)``: ``(B, k) -> (B, k, k)`` (with ``inverse``, ``A⁻¹`` by a Cholesky
        solve)."""
        a = self.factor_matrix(q)
        return spd_inverse(a) if self.inverse else a

    def inverse_mass(self, q: Tensor) -> Tensor:
        """``M_θ(q)⁻¹``: ``(B, k) -> (B, k, k)``."""
        a = self.factor_matrix(q)
        return a if self.inverse else spd_inverse(a)

    def potential(self, q: Tensor) -> Tensor:
        """``V_θ(q)``: ``(B, k) -> (B,)``."""
        return self.outputs(q)[1]

    @property
    def closed_form(self) -> bool:
        """Whether the networks are ``tanh`` MLPs (:meth:`linearize` applies)."""
        nets = [self.net] if self.shared else [self.mass_net, self.potential_net]
        return all(getattr(n, "activation", None) == "tanh" for n in nets)

    def linearize(self, q: Tensor) -> MechanicalLinearization:
        """:class:`MechanicalLinearization` at ``q (B, k)`` (``tanh`` networks)."""
        n = self.cholesky.size
        if self.shared:
            hs = (self.net.activations(q),)
            raw = self.net.out(hs[0][-1])[..., :n]
        else:
            hs = (self.mass_net.activations(q), self.potential_net.activations(q))
            raw = self.mass_net.out(hs[0][-1])
        f = self.cholesky.lower(raw)
        return MechanicalLinearization(self, q, hs, f, self.cholesky.from_factor(f))


class MechanicalHamiltonianField(nn.Module):
    """``H_θ = ½ pᵀ M_θ(q)⁻¹ p + V_θ(q)`` and its field (:func:`mechanical_hamiltonian_field`)
    on ``y = (q, p)``: an HNN whose kinetic energy is quadratic in ``p`` with a positive
    definite learned mass matrix. With ``nets.inverse`` the networks give
    ``A = M_θ⁻¹`` and ``dy/dt = (Ap, −½ ∂(pᵀAp)/∂q − ∇V_θ)`` (no solve).

    Args:
        nets: the learned ``M_θ`` and ``V_θ`` (:class:`MechanicalNets`).
    """

    def __init__(self, nets: MechanicalNets) -> None:
        super().__init__()
        self.nets = nets

    def hamiltonian(self, y: Tensor) -> Tensor:
        """``H_θ(y)``: ``(B, 2k) -> (B,)``."""
        q, p = y.chunk(2, -1)
        raw, potential = self.nets.outputs(q)
        a = self.nets.cholesky(raw)
        u = (a @ p[..., None])[..., 0] if self.nets.inverse else spd_solve(a, p)
        return 0.5 * (p * u).sum(-1) + potential

    def forward(self, y: Tensor) -> Tensor:
        return self.vector_field(None, y)

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``dy/dt = (M_θ⁻¹p, ½ ∂(uᵀM_θu)/∂q − ∇V_θ)``, ``u = M_θ⁻¹p``: ``(B, 2k) -> (B, 2k)``;
        in closed form for ``tanh`` networks (:meth:`CholeskyMass.linearize`)."""
        q, p = usable(y).chunk(2, -1)
        if not self.nets.closed_form:
            return mechanical_hamiltonian_field(self.nets.mass, self.nets.potential, q, p)
        lin = self.nets.linearize(q)
        if self.nets.inverse:
            return torch.cat([(lin.mass @ p[..., None])[..., 0], lin.force(p, -1.0)], -1)
        u = spd_solve(lin.mass, p)
        return torch.cat([u, lin.force(u)], -1)


class MechanicalLagrangianField(VelocityField):
    """``L_θ = ½ q̇ᵀ M_θ(q) q̇ − V_θ(q)`` (the Lagrangian twin of
    :class:`MechanicalHamiltonianField`) on ``x = (q, q̇)``: accelerations by
    :func:`mechanical_acceleration` (a Cholesky solve with ``M_θ``, never singular);
    energy ``½ q̇ᵀ M_θ q̇ + V_θ``. With ``nets.inverse`` (``A = M_θ⁻¹``), ``w = A⁻¹q̇``
    (the momenta, one Cholesky solve) and
    ``q̈ = (Σ_j ∂A/∂q_j q̇_j) w − A (½ ∂(wᵀAw)/∂q + ∇V_θ)``, i.e. ``d/dt (A p)``
    along the Hamiltonian field.

    Args:
        nets: the learned ``M_θ`` and ``V_θ`` (:class:`MechanicalNets`).
    """

    def __init__(self, nets: MechanicalNets) -> None:
        super().__init__()
        self.nets = nets

    def acceleration(self, q: Tensor, v: Tensor) -> Tensor:
        q, v = usable(q), usable(v)
        if not self.nets.closed_form:
            return mechanical_acceleration(self.nets.mass, self.nets.potential, q, v)
        lin = self.nets.linearize(q)
        if self.nets.inverse:
            w = spd_solve(lin.mass, v)
            return lin.action_jvp(w, v) + (lin.mass @ lin.force(w, -1.0)[..., None])[..., 0]
        rhs = lin.force(v) - lin.action_jvp(v, v)
        return spd_solve(lin.mass, rhs)

    def energy(self, x: Tensor) -> Tensor:
        q, v = x.chunk(2, -1)
        raw, potential = self.nets.outputs(q)
        a = self.nets.cholesky(raw)
        p = spd_solve(a, v) if self.nets.inverse else (a @ v[..., None])[..., 0]
        return 0.5 * (v * p).sum(-1) + potential
