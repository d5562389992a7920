"""The chain pendulum, its data on the constrained-HNN protocol, and the benchmark's metric."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from hnn_pl.data import ChainPendulumData
from hnn_pl.evaluation.metrics import relative_rollout_error, relative_state_error
from hnn_pl.integrate import odeint
from hnn_pl.systems import ChainPendulum, DoublePendulum, HamiltonianSystem, Pendulum
from hnn_pl.systems.chain_pendulum import VelocityChart, reference_parameters

F64 = torch.float64


def _states(system: ChainPendulum, n: int = 64, seed: int = 0) -> torch.Tensor:
    return system.sample_initial(n, torch.Generator().manual_seed(seed))


def test_reference_parameters_are_numpy_seed_0_draws_handed_out_from_the_end():
    u = np.random.RandomState(0).rand(4)
    masses, lengths = reference_parameters(2)
    assert masses == pytest.approx((0.6 + 0.8 * u[1], 0.6 + 0.8 * u[0]), abs=1e-15)
    assert lengths == pytest.approx((0.6 + 0.8 * u[3], 0.6 + 0.8 * u[2]), abs=1e-15)
    assert all(0.6 <= v <= 1.4 for v in (*masses, *lengths))
    s = DoublePendulum()
    assert (s.n, s.masses, s.lengths, s.g) == (2, masses, lengths, 9.81)
    with pytest.raises(ValueError, match="masses must be 3 positive"):
        ChainPendulum(3, masses=(1.0, 1.0))


def test_double_pendulum_mass_matrix_and_potential_are_the_textbook_forms():
    m1, m2, l1, l2, g = 0.7, 1.3, 1.1, 0.8, 9.81
    s = DoublePendulum((m1, m2), (l1, l2), g)
    q = torch.randn(50, 2, generator=torch.Generator().manual_seed(1), dtype=F64) * 3
    c = torch.cos(q[:, 0] - q[:, 1])
    want = torch.stack(
        [
            torch.stack([(m1 + m2) * l1**2 * torch.ones_like(c), m2 * l1 * l2 * c], -1),
            torch.stack([m2 * l1 * l2 * c, m2 * l2**2 * torch.ones_like(c)], -1),
        ],
        -2,
    )
    torch.testing.assert_close(s.mass_matrix(q), want, rtol=0, atol=1e-14)
    v_want = -(m1 + m2) * g * l1 * torch.cos(q[:, 0]) - m2 * g * l2 * torch.cos(q[:, 1])
    torch.testing.assert_close(s.potential(q), v_want, rtol=0, atol=1e-13)
    assert bool((torch.linalg.eigvalsh(s.mass_matrix(q)) > 0).all())


def test_one_link_is_the_pendulum():
    m, l, g = 0.9, 1.2, 9.81
    chain, pend = (
        ChainPendulum(1, (m,), (l,), g),
        Pendulum(alpha=m * g * l, beta=1 / (2 * m * l**2)),
    )
    y = torch.randn(40, 2, generator=torch.Generator().manual_seed(2), dtype=F64) * 2
    torch.testing.assert_close(chain.vector_field(None, y), pend.vector_field(None, y))
    torch.testing.assert_close(chain.hamiltonian(y) + m * g * l, pend.hamiltonian(y))


@pytest.mark.parametrize("n", [2, 3])
def test_closed_forms_agree_with_autograd_and_the_euler_lagrange_equations(n):
    s = ChainPendulum(n)
    y = _states(s)
    q, p = y.chunk(2, -1)
    f = s.vector_field(None, y)
    torch.testing.assert_close(f, HamiltonianSystem.vector_field(s, None, y), rtol=0, atol=1e-11)
    v = s.velocity(q, p)
    torch.testing.assert_close(f[:, :n], v)
    torch.testing.assert_close(s.momentum_qv(q, v), p)
    torch.testing.assert_close(HamiltonianSystem.momentum_qv(s, q, v), p, rtol=0, atol=1e-10)
    torch.testing.assert_close(s.energy_qv(q, v), s.hamiltonian(y), rtol=0, atol=1e-12)

    # Euler–Lagrange from autograd of L: ∂²L/∂v² q̈ = ∂L/∂q − ∂²L/∂v∂q v
    def lag(x):
        return s.lagrangian(x[:n], x[n:])

    x = torch.cat([q, v], -1)
    hess = torch.func.vmap(torch.func.hessian(lag))(x)
    grad = torch.func.vmap(torch.func.grad(lag))(x)
    rhs = grad[:, :n] - (hess[:, n:, :n] @ v[..., None])[..., 0]
    want = torch.linalg.solve(hess[:, n:, n:], rhs)
    torch.testing.assert_close(s.acceleration(q, v), want, rtol=0, atol=1e-10)
    chart = VelocityChart(s)
    torch.testing.assert_close(chart.vector_field(None, x), torch.cat([v, want], -1))
    torch.testing.assert_close(chart.hamiltonian(x), s.hamiltonian(y))


@pytest.mark.parametrize("n", [2, 3])
def test_energy_is_conserved_by_the_symplectic_integrator(n):
    """Implicit midpoint (symplectic for any H; leapfrog needs a separable one) keeps the
    energy error at its O(h²) modified-energy oscillation: halving h divides it by 4."""
    s = ChainPendulum(n)
    y0 = _states(s, 16)
    q, p = y0.chunk(2, -1)
    scale = s.potential(q).abs() + 0.5 * (p * s.velocity(q, p)).sum(-1)

    def max_error(h):
        t = torch.arange(round(2 / h) + 1, dtype=F64) * h
        e = s.hamiltonian(odeint(s.vector_field, y0, t, "implicit_midpoint", rtol=0, atol=1e-13))
        return ((e - e[0]).abs() / scale).amax(0)

    coarse, fine = max_error(0.01), max_error(0.005)
    assert float(fine.max()) < 5e-3
    ratio = coarse / fine
    assert 3.5 < float(ratio.median()) < 4.5 and float(ratio.min()) > 2.5
    t = torch.arange(101, dtype=F64) * 0.03
    e = s.hamiltonian(s.trajectory(y0, t))
    torch.testing.assert_close(e, e[:1].expand(101, -1), rtol=1e-6, atol=0)  # the truth


def test_cartesian_map_inverse_projection_and_sampler():
    s = ChainPendulum(3)
    q, v = s.sample_qv(32, torch.Generator().manual_seed(3))
    z = s.cartesian_qv(q, v)
    assert z.shape == (32, 2, 3, 2)
    torch.testing.assert_close(z[:, 0], s.cartesian(q))
    assert float(s.constraints(z).abs().max()) < 1e-10
    q2, v2 = s.angles_qv(z)
    torch.testing.assert_close(q2, q)
    torch.testing.assert_close(v2, v)
    noisy = z + 1e-2 * torch.randn(z.shape, generator=torch.Generator().manual_seed(4), dtype=F64)
    jac = torch.func.vmap(torch.func.jacrev(lambda w: s.constraints(w.reshape(2, 3, 2))))
    torch.testing.assert_close(s.constraints_jacobian(noisy), jac(noisy.reshape(32, -1)))
    back = s.project(noisy)
    assert float(s.constraints(back).abs().max()) < 1e-10
    assert 0 < float((back - z).abs().max()) < 0.05
    again = s.sample_qv(32, torch.Generator().manual_seed(3))
    assert torch.equal(again[0], q) and torch.equal(again[1], v)
    assert not torch.equal(s.sample_qv(32, torch.Generator().manual_seed(5))[0], q)


def test_metric_equals_a_hand_computation():
    z_true = torch.tensor([[[3.0, 4.0], [3.0, 4.0], [1.0, 0.0]]], dtype=F64)
    z_pred = torch.tensor([[[3.0, 4.0], [0.0, 0.0], [0.0, 1.0]]], dtype=F64)
    err = relative_state_error(z_pred, z_true)
    torch.testing.assert_close(err, torch.tensor([[0.0, 1.0, math.sqrt(2) / 2]], dtype=F64))
    alt = relative_state_error(z_pred, z_true, "norm_of_sum")
    torch.testing.assert_close(alt, torch.tensor([[0.0, 1.0, 1.0]], dtype=F64))
    dt = 0.5
    logs = [math.log(1e-8), math.log(1 + 1e-8), math.log(math.sqrt(2) / 2 + 1e-8)]
    integral = dt * (logs[0] / 2 + logs[1] + logs[2] / 2)
    got = relative_rollout_error(z_pred, z_true, dt)
    torch.testing.assert_close(got, torch.tensor([math.exp(integral / 1.0)], dtype=F64))
    over_3s = relative_rollout_error(z_pred, z_true, dt, horizon=3.0)
    torch.testing.assert_close(over_3s, torch.tensor([math.exp(integral / 3.0)], dtype=F64))
    stopped = relative_rollout_error(torch.full_like(z_pred, math.nan), z_true, dt)
    torch.testing.assert_close(stopped, torch.tensor([1 + 1e-8], dtype=F64))


def _data(tmp_path, **kw):
    args = {"n_train": 6, "n_pool": 12, "n_val": 4, "n_test": 5, "horizon": 0.6}
    args["cache_dir"] = str(tmp_path)
    dm = ChainPendulumData(**{**args, **kw})
    dm.setup()
    return dm


def test_data_shapes_batches_and_determinism(tmp_path):
    dm = _data(tmp_path / "a")
    assert dm.state_dim == 4 and dm.test_t.shape == (20,) and dm.test_y.shape == (20, 5, 4)
    assert dm.x_train.shape == dm.dx_train.shape == (30, 4) and dm.x_test.shape == (20, 4)
    assert torch.allclose(dm.test_t[1:] - dm.test_t[:-1], torch.tensor(0.03))
    (y, t, index), *_ = list(dm.train_dataloader())
    assert y.shape == (6, 5, 4) and t.shape == index.shape == (6, 5)
    steps = t[:, 1:] - t[:, :-1]
    assert torch.allclose(steps, torch.full_like(steps, 0.03))
    starts = (t[:, 0] / 0.15).double()
    assert torch.allclose(starts, starts.round(), atol=1e-4)  # chunks start on k · 5 dt
    assert dm.n_train_trajectories == 6 and dm.n_test_trajectories == 4
    other = _data(tmp_path / "b", seed=7)
    for key in ("x_train", "x_test", "test_y", "obs_t_train"):
        assert torch.equal(getattr(dm, key), getattr(other, key)), key
    bigger = _data(tmp_path / "c", n_train=12)
    assert torch.equal(bigger.x_train[:30], dm.x_train)  # the smaller set is a prefix
    assert not torch.allclose(dm.x_test, dm.x_train[:20])  # validation: its own seed
    torch.testing.assert_close(dm.system.vector_field(None, dm.x_train), dm.dx_train)


def test_scores_in_both_coordinates(tmp_path):
    dm = _data(tmp_path / "a", dtype="float64")
    vel = _data(tmp_path / "b", dtype="float64", coordinates="velocity")
    torch.testing.assert_close(vel.test_y, vel.system.from_canonical(dm.test_y))
    torch.testing.assert_close(vel.dx_train, vel.system.vector_field(None, vel.x_train))
    torch.testing.assert_close(dm.cartesian(dm.test_y), vel.cartesian(vel.test_y))
    exact = dm.rollout_errors(dm.chain)
    assert float(exact.max()) < 1e-5
    torch.testing.assert_close(
        vel.rollout_errors(vel.system.vector_field), exact, rtol=0.5, atol=1e-6
    )
    floor = dm.chaos_floor()
    assert floor.shape == (5,) and 1e-6 < float(floor.median()) < 1e-3
    torch.testing.assert_close(vel.chaos_floor(), floor, rtol=1e-6, atol=0)
    frozen = dm.rollout_errors(lambda t, y: torch.zeros_like(y))
    assert float(frozen.min()) > 1e-2
    blowup = dm.rollout_errors(lambda t, y: 50 * y * y.abs())
    assert bool(((blowup > 0.1) & (blowup <= 1 + 1e-8)).all())


def test_a_trajectory_beyond_the_step_budget_scores_as_stopped(tmp_path):
    """The exact field within a budget of 3 dopri5 steps per test trajectory stops
    short of the horizon (0.6 s at tolerance 1e-7 takes more): each row counts error 1
    from where it stopped, so its geometric mean lies far above the exact score and at
    most 1; with the default budget the same field scores below 1e-5."""
    from hnn_pl.data.chain_pendulum import SCORE_MAX_STEPS

    dm = _data(tmp_path, dtype="float64")
    assert SCORE_MAX_STEPS >= 1000
    assert float(dm.rollout_errors(dm.chain).max()) < 1e-5
    cut = dm.rollout_errors(dm.chain, max_steps=3)
    assert bool(((cut > 1e-3) & (cut <= 1 + 1e-8)).all())
