"""Lagrangian and mass-matrix-structured models: exact accelerations for exact Lagrangians,
positive definite learned mass matrices, the singular guard, the (q, p) ↔ (q, q̇) chart,
and a few training steps of each model."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from hnn_pl import HNN, LNN, Baseline, DissipativeHNN, MechanicalHNN, MechanicalLNN
from hnn_pl.models.velocity import VelocityChart
from hnn_pl.nets import MLP
from hnn_pl.nets.lagrangian import (
    LagrangianField,
    MechanicalHamiltonianField,
    MechanicalLagrangianField,
    MechanicalNets,
    euler_lagrange,
    lagrangian_energy,
    lagrangian_terms,
    lagrangian_terms_autograd,
    mechanical_acceleration,
    mechanical_hamiltonian_field,
    mlp_lagrangian_terms,
    spd_inverse,
)
from hnn_pl.safe_io import class_name
from hnn_pl.systems import MassSpring, Pendulum
from hnn_pl.systems.base import system_spec

TERMS = {"torch.func": lagrangian_terms, "double autograd": lagrangian_terms_autograd}

# the double pendulum: point masses m1, m2 on rods l1, l2, angles from the downward vertical
M1, M2, L1, L2, G = 1.0, 1.3, 0.9, 1.1, 9.81


def dp_mass(q: torch.Tensor) -> torch.Tensor:
    """``M(q) = [[(m1+m2) l1², m2 l1 l2 cos(q1−q2)], [·, m2 l2²]]``: ``(B, 2) -> (B, 2, 2)``."""
    c = torch.cos(q[..., 0] - q[..., 1])
    a11 = torch.full_like(c, (M1 + M2) * L1**2)
    a22 = torch.full_like(c, M2 * L2**2)
    a12 = M2 * L1 * L2 * c
    return torch.stack([torch.stack([a11, a12], -1), torch.stack([a12, a22], -1)], -2)


def dp_potential(q: torch.Tensor) -> torch.Tensor:
    """``V = −(m1+m2) g l1 cos q1 − m2 g l2 cos q2``."""
    return -(M1 + M2) * G * L1 * torch.cos(q[..., 0]) - M2 * G * L2 * torch.cos(q[..., 1])


def dp_lagrangian(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return 0.5 * (v * (dp_mass(q) @ v[..., None])[..., 0]).sum(-1) - dp_potential(q)


def dp_acceleration(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """The textbook closed form of the double pendulum's angular accelerations."""
    t1, t2, w1, w2 = q[:, 0], q[:, 1], v[:, 0], v[:, 1]
    d = t1 - t2
    den = 2 * M1 + M2 - M2 * torch.cos(2 * d)
    a1 = (
        -G * (2 * M1 + M2) * torch.sin(t1)
        - M2 * G * torch.sin(t1 - 2 * t2)
        - 2 * torch.sin(d) * M2 * (w2**2 * L2 + w1**2 * L1 * torch.cos(d))
    ) / (L1 * den)
    a2 = (
        2
        * torch.sin(d)
        * (w1**2 * L1 * (M1 + M2) + G * (M1 + M2) * torch.cos(t1) + w2**2 * L2 * M2 * torch.cos(d))
    ) / (L2 * den)
    return torch.stack([a1, a2], -1)


def spring_lagrangian(system: MassSpring):
    """``L = q̇²/(4β) − α q²`` of ``H = α q² + β p²``."""
    return lambda q, v: (v**2 / (4 * system.beta) - system.alpha * q**2).sum(-1)


def pendulum_lagrangian(system: Pendulum):
    """``L = q̇²/(4β) − α(1 − cos q)`` of ``H = α(1 − cos q) + β p²``."""
    return lambda q, v: (v**2 / (4 * system.beta) - system.alpha * (1 - torch.cos(q))).sum(-1)


class Exact(nn.Module):
    """An exact ``L(q, q̇)`` as a network ``(B, 2k) -> (B, 1)``."""

    def __init__(self, lagrangian) -> None:
        super().__init__()
        self.lagrangian = lagrangian

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        q, v = x.chunk(2, -1)
        return self.lagrangian(q, v)[..., None]


def states(n: int, k: int, seed: int = 0, scale: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return (scale * torch.randn(n, 2 * k, generator=g, dtype=torch.float64)).chunk(2, -1)


# ------------------------------------------------------------------ exact accelerations


@pytest.mark.parametrize("terms", TERMS)
@pytest.mark.parametrize("system", [MassSpring(), MassSpring(0.5, 0.5), Pendulum()])
def test_euler_lagrange_exact_for_spring_and_pendulum(terms, system):
    """The LNN's Euler–Lagrange solve on the exact L gives the system's own q̈ (its
    field's d/dt ∂H/∂p through the chart)."""
    lag = (spring_lagrangian if isinstance(system, MassSpring) else pendulum_lagrangian)(system)
    g = torch.Generator().manual_seed(1)
    y = 2 * torch.randn(64, 2, generator=g, dtype=torch.float64)
    chart = VelocityChart(system)
    x, rates = chart.to_velocity(y), chart.rates(y, system.vector_field(None, y))
    q, v = x.chunk(2, -1)
    out = euler_lagrange(lag, q, v, terms=TERMS[terms])
    assert not out.singular.any()
    torch.testing.assert_close(out.acceleration, rates[:, 1:], rtol=1e-12, atol=1e-12)
    if isinstance(system, Pendulum):
        expected = -2 * system.alpha * system.beta * torch.sin(q)
    else:
        expected = -4 * system.alpha * system.beta * q
    torch.testing.assert_close(out.acceleration, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("terms", TERMS)
def test_euler_lagrange_exact_for_double_pendulum(terms):
    q, v = states(128, 2, seed=2, scale=1.5)
    out = euler_lagrange(dp_lagrangian, q, v, terms=TERMS[terms])
    assert not out.singular.any()
    torch.testing.assert_close(out.acceleration, dp_acceleration(q, v), rtol=1e-10, atol=1e-10)


def test_lnn_field_with_exact_lagrangian_is_the_systems_field():
    """An LNN whose network is the exact L, read through the spring's chart: its field in
    (q, p) is the system's J∇H and its energy q̇·∂L/∂q̇ − L is H."""
    for system, lag in ((MassSpring(), spring_lagrangian), (Pendulum(), pendulum_lagrangian)):
        field = LagrangianField(Exact(lag(system)))
        field.chart = VelocityChart(system)
        y = 1.5 * torch.randn(50, 2, generator=torch.Generator().manual_seed(3)).double()
        torch.testing.assert_close(field.vector_field(None, y), system.vector_field(None, y))
        torch.testing.assert_close(field.hamiltonian(y), system.hamiltonian(y))
        with torch.inference_mode():
            torch.testing.assert_close(field.hamiltonian(y), system.hamiltonian(y))


def test_lnn_energy_is_h_for_the_exact_spring():
    system = MassSpring(0.7, 1.3)
    q, v = states(40, 1, seed=4)
    p = system.momentum_qv(q, v)
    e = lagrangian_energy(spring_lagrangian(system), q, v)
    torch.testing.assert_close(e, system.hamiltonian(torch.cat([q, p], -1)))


@pytest.mark.parametrize("n_hidden", [1, 2, 3])
def test_closed_form_terms_equal_torch_func(n_hidden):
    """The tanh MLP's closed-form Hessian blocks are torch.func's, and so are the parameter
    gradients of a loss on the accelerations."""
    torch.manual_seed(n_hidden)
    net = MLP(4, 1, 24, n_hidden).double()
    q, v = states(32, 2, seed=5)
    closed = mlp_lagrangian_terms(net, q, v)
    generic = lagrangian_terms(lambda a, b: net(torch.cat([a, b], -1))[..., 0], q, v)
    for a, b in zip(closed, generic):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    grads = []
    for terms in (None, lagrangian_terms):
        field = LagrangianField(net, kinetic_prior=0.7, terms=terms)
        loss = field.acceleration(q, v).pow(2).mean()
        grads.append(torch.autograd.grad(loss, list(net.parameters())))
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, rtol=1e-8, atol=1e-10)


# ------------------------------------------------------------------ the structured models


def test_mechanical_hamiltonian_field_exact_for_double_pendulum():
    q, v = states(128, 2, seed=6, scale=1.5)
    p = (dp_mass(q) @ v[..., None])[..., 0]
    f = mechanical_hamiltonian_field(dp_mass, dp_potential, q, p)
    torch.testing.assert_close(f[:, :2], v, rtol=1e-12, atol=1e-12)
    # dp/dt = d/dt (M q̇) = M q̈ + (Σ_j ∂M/∂q_j q̇_j) q̇ along the true motion
    _, dm_v = torch.func.jvp(lambda a: (dp_mass(a) @ v[..., None])[..., 0], (q,), (v,))
    p_dot = (dp_mass(q) @ dp_acceleration(q, v)[..., None])[..., 0] + dm_v
    torch.testing.assert_close(f[:, 2:], p_dot, rtol=1e-10, atol=1e-10)


def test_mechanical_acceleration_exact_for_double_pendulum():
    q, v = states(128, 2, seed=7, scale=1.5)
    a = mechanical_acceleration(dp_mass, dp_potential, q, v)
    torch.testing.assert_close(a, dp_acceleration(q, v), rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("shared", [True, False])
def test_structured_fields_closed_form_equal_generic(shared):
    torch.manual_seed(8)
    nets = MechanicalNets(3, 24, 2, "tanh", shared=shared).double()
    y = torch.randn(20, 6, dtype=torch.float64)
    q, p = y.chunk(2, -1)
    generic = mechanical_hamiltonian_field(nets.mass, nets.potential, q, p)
    torch.testing.assert_close(MechanicalHamiltonianField(nets)(y), generic, rtol=1e-10, atol=1e-12)
    generic = mechanical_acceleration(nets.mass, nets.potential, q, p)
    got = MechanicalLagrangianField(nets).acceleration(q, p)
    torch.testing.assert_close(got, generic, rtol=1e-10, atol=1e-12)


def test_mechanical_hnn_field_is_hamiltonian():
    """The structured HNN's field is J∇H_θ of its own H_θ = ½pᵀM⁻¹p + V."""
    torch.manual_seed(9)
    model = MechanicalHNN(input_dim=4, hidden_dim=16).double()
    y = torch.randn(10, 4, dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(model.hamiltonian(y).sum(), y)
    torch.testing.assert_close(model(y.detach()), torch.cat([g[:, 2:], -g[:, :2]], -1))


@pytest.mark.parametrize("shared", [True, False])
def test_learned_mass_matrix_is_positive_definite(shared):
    """``M_θ = LLᵀ + εI`` (``inverse_mass=False``): symmetric, eigenvalues ≥ ε."""
    for seed in range(20):
        torch.manual_seed(seed)
        model = MechanicalHNN(
            input_dim=6, hidden_dim=32, shared_trunk=shared, inverse_mass=False
        ).double()
        for scale in (0.1, 3.0, 30.0):
            q = scale * torch.randn(200, 3, dtype=torch.float64)
            m = model.mass_matrix(q)
            torch.testing.assert_close(m, m.transpose(-1, -2), rtol=0, atol=0)
            assert torch.linalg.eigvalsh(m).min() >= 0.999 * model.mass_eps


# ------------------------------------------------------------------ angles and M⁻¹


@pytest.mark.parametrize("pairs", [False, True])
def test_angle_features_closed_forms_equal_autograd(pairs):
    """An MLP reading x_0, x_2 as (cos, sin) (and their difference and sum with
    ``angle_pairs``): 2π-periodic in them, and its closed-form input gradient,
    vector–Jacobian and Jacobian–vector products are autograd's."""
    torch.manual_seed(20)
    net = MLP(4, 3, 16, 2, angles=[2, 0], angle_pairs=pairs).double()
    assert net.angles == (0, 2) and net.hidden[0].in_features == (10 if pairs else 6)
    x = 4 * torch.randn(7, 4, dtype=torch.float64)
    turns = 2 * math.pi * torch.tensor([3.0, 0.0, -5.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(net(x + turns), net(x), rtol=0, atol=1e-12)
    assert not torch.allclose(net(x + 0.5 * turns), net(x))
    jac = torch.stack([torch.func.jacrev(lambda z: net(z[None])[0])(row) for row in x])
    _, g = net.value_and_input_grad(x)
    torch.testing.assert_close(g, jac[:, 0], rtol=1e-10, atol=1e-12)
    hs, c, u = net.activations(x), torch.randn(7, 3).double(), torch.randn(7, 4).double()
    torch.testing.assert_close(net.input_vjp(hs, c, x), torch.einsum("bo,boi->bi", c, jac))
    torch.testing.assert_close(net.input_jvp(hs, u, x), torch.einsum("boi,bi->bo", jac, u))
    with pytest.raises(ValueError, match="needs its input x"):
        net.input_vjp(hs, c)
    for bad in ([4], [-1], [1, 1], [True]):
        with pytest.raises(ValueError, match="angles"):
            MLP(4, 1, angles=bad)
    with pytest.raises(ValueError, match="two angles or more"):
        MLP(4, 1, angles=[0], angle_pairs=True)


@pytest.mark.parametrize("pairs", [False, True])
def test_lnn_terms_with_angles_equal_torch_func(pairs):
    """The LNN's closed-form Hessian blocks through the (cos q, sin q) features (and the
    pairs') are torch.func's of the same L; angles of q̇ are refused."""
    torch.manual_seed(21)
    net = MLP(4, 1, 24, 2, angles=[0, 1], angle_pairs=pairs).double()
    q, v = states(32, 2, seed=22, scale=3.0)
    closed = mlp_lagrangian_terms(net, q, v)
    generic = lagrangian_terms(lambda a, b: net(torch.cat([a, b], -1))[..., 0], q, v)
    for a, b in zip(closed, generic):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="index q"):
        mlp_lagrangian_terms(MLP(4, 1, 8, angles=[2]).double(), q, v)


def test_spd_inverse_has_the_right_jacobian_vector_product():
    """``M_θ = A⁻¹`` for the inverse-mass models: value and forward-mode derivative (the
    Lagrangian twin's Coriolis term) equal finite differences."""
    g = torch.Generator().manual_seed(23)
    b = torch.randn(5, 3, 3, generator=g, dtype=torch.float64)
    a = b @ b.mT + torch.eye(3, dtype=torch.float64)
    da = torch.randn(5, 3, 3, generator=g, dtype=torch.float64)
    da = da + da.mT
    value, tangent = torch.func.jvp(spd_inverse, (a,), (da,))
    torch.testing.assert_close(value @ a, torch.eye(3, dtype=torch.float64).expand(5, 3, 3))
    h = 1e-6
    fd = (spd_inverse(a + h * da) - spd_inverse(a - h * da)) / (2 * h)
    torch.testing.assert_close(tangent, fd, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("inverse", [False, True])
@pytest.mark.parametrize(("shared", "pairs"), [(True, False), (False, False), (False, True)])
def test_structured_fields_with_angles_and_inverse_mass_equal_generic(inverse, shared, pairs):
    """With (cos, sin) features (and the pairs') and/or M⁻¹ learned, the closed-form
    fields are the torch.func ones of the same M_θ, V_θ, the Hamiltonian field is J∇H_θ
    of its own H_θ, and the Lagrangian twin's q̈ is d/dt of the Hamiltonian field's
    velocity."""
    torch.manual_seed(24)
    nets = MechanicalNets(2, 24, 2, "tanh", 1e-3, shared, [0, 1], inverse, pairs).double()
    y = 3 * torch.randn(20, 4, dtype=torch.float64)
    q, w = y.chunk(2, -1)
    field = MechanicalHamiltonianField(nets)
    got = field(y)
    torch.testing.assert_close(
        got, mechanical_hamiltonian_field(nets.mass, nets.potential, q, w), rtol=1e-10, atol=1e-11
    )
    yg = y.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(field.hamiltonian(yg).sum(), yg)
    torch.testing.assert_close(got, torch.cat([g[:, 2:], -g[:, :2]], -1))
    acc = MechanicalLagrangianField(nets).acceleration(q, w)
    generic = mechanical_acceleration(nets.mass, nets.potential, q, w)
    torch.testing.assert_close(acc, generic, rtol=1e-9, atol=1e-10)
    z = torch.cat([q, (nets.mass(q) @ w[..., None])[..., 0]], -1)  # (q, p) with q̇ = w
    h = 1e-6
    fd = (field(z + h * field(z))[:, :2] - field(z - h * field(z))[:, :2]) / (2 * h)
    torch.testing.assert_close(acc, fd, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("shared", [True, False])
def test_learned_inverse_mass_is_positive_definite(shared):
    """``M_θ⁻¹ = LLᵀ + εI``: symmetric with eigenvalues ≥ ε for random weights, at
    angles turned far (cos/sin features) or not; ``M_θ`` its inverse."""
    for seed in range(10):
        torch.manual_seed(seed)
        model = MechanicalHNN(
            input_dim=6, hidden_dim=32, shared_trunk=shared, inverse_mass=True, angles=[0, 2]
        ).double()
        for scale in (0.1, 3.0, 30.0):
            q = scale * torch.randn(200, 3, dtype=torch.float64)
            a = model.field.nets.factor_matrix(q)
            torch.testing.assert_close(a, a.transpose(-1, -2), rtol=0, atol=0)
            assert torch.linalg.eigvalsh(a).min() >= 0.999 * model.mass_eps
            eye = torch.eye(3, dtype=torch.float64).expand(200, 3, 3)
            torch.testing.assert_close(model.mass_matrix(q) @ a, eye)


@pytest.mark.parametrize("cls", [HNN, Baseline, LNN, MechanicalHNN, MechanicalLNN])
def test_models_with_angles_are_periodic_in_them(cls):
    """Every model that takes ``angles`` gives the same field a whole turn away in
    them (and not half a turn); one whose networks cannot read them refuses them."""
    torch.manual_seed(25)
    model = cls(input_dim=4, hidden_dim=16, angles=[0, 1]).double()
    y = 2 * torch.randn(6, 4, dtype=torch.float64)
    turn = torch.tensor([2 * math.pi, -4 * math.pi, 0.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(model(y + turn), model(y), rtol=1e-9, atol=1e-9)
    assert not torch.allclose(model(y + turn / 4), model(y))
    assert model.hparams.angles == [0, 1]
    paired = cls(input_dim=4, hidden_dim=16, angles=[0, 1], angle_pairs=True).double()
    torch.testing.assert_close(paired(y + turn), paired(y), rtol=1e-9, atol=1e-9)
    assert not torch.allclose(paired(y + turn / 4), paired(y))
    assert paired.hparams.angle_pairs is True
    with pytest.raises(ValueError, match="angles must be indices"):
        cls(input_dim=4, hidden_dim=8, angles=[2])
    with pytest.raises(ValueError, match="two angles or more"):
        cls(input_dim=4, hidden_dim=8, angles=[1], angle_pairs=True)
    with pytest.raises(ValueError, match="do not read angles"):
        DissipativeHNN(input_dim=4, hidden_dim=8, angles=[0])


# ------------------------------------------------------------------ the singular guard


def test_singular_hessian_is_flagged_and_solved_or_refused():
    """``L = q·q̇ + |q|²`` has ``∂²L/∂q̇² = 0``: every row is flagged, the ridge solve is
    finite; ``on_singular="raise"`` refuses in one line; a regular L is not flagged."""
    q, v = states(16, 2, seed=10)

    def degenerate(a, b):
        return (a * b).sum(-1) + (a**2).sum(-1)

    out = euler_lagrange(degenerate, q, v)
    assert out.singular.all() and torch.isfinite(out.acceleration).all()
    with pytest.raises(FloatingPointError, match="16 of 16 states"):
        euler_lagrange(degenerate, q, v, on_singular="raise")
    field = LagrangianField(Exact(degenerate))
    field.acceleration(q, v)
    assert float(field.singular_fraction) == 1.0
    half = torch.cat([torch.ones(8), torch.zeros(8)]).double()[:, None]

    def some(a, b):  # singular on the rows where half = 0
        return 0.5 * (half * b**2).sum(-1) - (a**2).sum(-1)

    out = euler_lagrange(some, q, v)
    assert out.singular.tolist() == [False] * 8 + [True] * 8
    torch.testing.assert_close(out.acceleration[:8], -2 * q[:8])
    assert not euler_lagrange(dp_lagrangian, q, v).singular.any()


def test_lnn_logs_the_singular_fraction():
    model = LNN(input_dim=2, hidden_dim=16)
    y, dydt = torch.randn(12, 2), torch.randn(12, 2)
    parts = model.training_loss((y, dydt))
    assert set(parts) == {"loss", "singular_fraction"}
    assert 0.0 <= float(parts["singular_fraction"]) <= 1.0


# ------------------------------------------------------------------ data and training


def test_velocity_model_reads_qp_data_through_the_chart():
    system = MassSpring(alpha=1.0, beta=1.0)  # q̇ = 2p, q̈ = −4q
    model = LNN(input_dim=2, hidden_dim=8)
    model.attach_system(system)
    y = torch.randn(10, 2, dtype=torch.float64)
    x, rates = model._batch((y, system.vector_field(None, y)))
    torch.testing.assert_close(x, torch.stack([y[:, 0], 2 * y[:, 1]], -1))
    torch.testing.assert_close(rates, torch.stack([2 * y[:, 1], -4 * y[:, 0]], -1))
    windows = y.reshape(2, 5, 2)
    model = LNN(input_dim=2, hidden_dim=8, objective="trajectory")
    model.attach_system(system)
    xw, t, index = model._batch((windows, torch.zeros(2, 5), torch.zeros(2, 5)))
    torch.testing.assert_close(xw, torch.stack([windows[..., 0], 2 * windows[..., 1]], -1))
    model = LNN(input_dim=2, hidden_dim=8)
    assert model._batch((y, y))[0] is y


def test_positions_alone_start_windows_from_the_fitted_velocity():
    """Windows of positions (width k) are not converted; a held-out window starts at its
    first position with the velocity fitted to its first samples: (q, q̇), not a momentum."""
    model = LNN(input_dim=2, hidden_dim=8, objective="trajectory", learned_states="sample")
    model.attach_system(MassSpring())
    t = torch.linspace(0, 0.2, 5, dtype=torch.float64).expand(3, 5)
    amplitude = torch.tensor([[0.5], [1.0], [2.0]], dtype=torch.float64)
    q = (amplitude * (3 * t - 2 * t**2))[..., None]  # q̇(0) = 3a, exact for a quadratic fit
    y, *_ = model._batch((q, t, torch.zeros(3, 5, dtype=torch.long)))
    assert y is q
    start = model.window_starts(q, t)
    torch.testing.assert_close(start[:, 0], q[:, 0, 0])
    torch.testing.assert_close(start[:, 1], 3 * amplitude[:, 0])


@pytest.mark.parametrize("system", [MassSpring(0.7, 1.3), Pendulum()])
def test_chart_momentum_rate_closed_form_equals_hessian_form(system):
    """ṗ from the system's closed-form momentum_qv equals the general form from H's second
    derivatives, and along the true motion is the system's own dp/dt."""
    chart = VelocityChart(system)
    assert chart.closed_form
    y = torch.randn(30, 2, generator=torch.Generator().manual_seed(13), dtype=torch.float64)
    f = system.vector_field(None, y)
    x, rates = chart.to_velocity(y), chart.rates(y, f)
    closed = chart.momentum_rate(y, x, rates[:, 1:])
    chart.closed_form = False
    torch.testing.assert_close(chart.momentum_rate(y, x, rates[:, 1:]), closed)
    torch.testing.assert_close(closed, f[:, 1:])
    torch.testing.assert_close(chart.to_momentum(x), y)


def test_checkpoint_attaches_the_recorded_system():
    model = LNN(input_dim=2, hidden_dim=8)
    checkpoint = {
        "state_dict": model.state_dict(),
        "hnn_pl_model_class": class_name(LNN),
        "datamodule_hyper_parameters": {"system": system_spec(MassSpring(2.0, 0.5))},
    }
    other = LNN(input_dim=2, hidden_dim=8)
    other.load_trained(checkpoint)
    assert isinstance(other.chart.system, MassSpring) and other.chart.system.alpha == 2.0


def spring_batches(objective: str):
    """The spring's (q, p) data: derivative pairs, or 5-sample windows."""
    system = MassSpring()
    g = torch.Generator().manual_seed(11)
    y0 = system.sample_initial(16, g)
    t = torch.linspace(0, 1.2, 5, dtype=torch.float64)
    y = system.trajectory(y0, t).transpose(0, 1).float()  # (16, 5, 2)
    if objective == "trajectory":
        return system, (y, t.float().expand(16, 5), torch.zeros(16, 5, dtype=torch.long))
    flat = y.reshape(-1, 2)
    return system, (flat, system.vector_field(None, flat.double()).float())


@pytest.mark.parametrize("objective", ["derivative", "trajectory"])
@pytest.mark.parametrize("cls", [LNN, MechanicalHNN, MechanicalLNN])
def test_a_few_training_steps_reduce_the_loss(cls, objective):
    torch.manual_seed(12)
    system, batch = spring_batches(objective)
    model = cls(input_dim=2, hidden_dim=32, objective=objective)
    if hasattr(model, "attach_system"):
        model.attach_system(system)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        opt.zero_grad()
        loss = model.training_loss(batch)["loss"]
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert all(math.isfinite(x) for x in losses)
    assert losses[-1] < 0.7 * losses[0]


@pytest.mark.parametrize("activation", ["tanh", "softplus"])
@pytest.mark.parametrize("cls", [LNN, MechanicalHNN, MechanicalLNN])
def test_fields_under_inference_mode(cls, activation):
    """Closed-form (tanh) and torch.func (other activations) paths give the same field and
    energy under ``torch.inference_mode`` (Lightning's evaluation) as with gradients."""
    torch.manual_seed(14)
    model = cls(input_dim=2, hidden_dim=8, activation=activation)
    if hasattr(model, "attach_system"):
        model.attach_system(Pendulum())
    y = torch.randn(5, 2)
    expected, energy = model(y).detach(), model.hamiltonian(y).detach()
    with torch.inference_mode():
        y_inf = y.clone()
        torch.testing.assert_close(model(y_inf), expected)
        torch.testing.assert_close(model.hamiltonian(y_inf), energy)


def test_a_full_batch_is_converted_once():
    """The same tensors are converted once; new or modified ones anew."""
    system = MassSpring()
    model = LNN(input_dim=2, hidden_dim=8)
    model.attach_system(system)
    y = torch.randn(10, 2, dtype=torch.float64)
    dydt = system.vector_field(None, y)
    first = model._batch((y, dydt))
    assert model._batch((y, dydt)) is first
    assert model._batch((y.clone(), dydt)) is not first
    y.mul_(2.0)
    again = model._batch((y, dydt))
    torch.testing.assert_close(again[0][:, 0], y[:, 0])
