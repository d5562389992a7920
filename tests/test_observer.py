"""The observer (a start inferred from positions) and the gauge-invariant metrics.

Positions are the paper's pendulum grid, 15 samples a second (``linspace(0, 3, 45)``);
"15 samples" is the first second.
"""

from __future__ import annotations

import pytest
import torch
from torch import Tensor, nn

from hnn_pl.evaluation import (
    ObserverStatus,
    infer_starts,
    observe,
    position_mse,
    position_valid_time,
    velocity_energy,
    velocity_energy_mse,
)
from hnn_pl.evaluation.metrics import valid_time_of
from hnn_pl.integrate import odeint
from hnn_pl.models import HNN
from hnn_pl.systems import HamiltonianSystem, MassSpring, Pendulum, ThreeBody, TwoBody

F64 = torch.float64
GRID = torch.linspace(0, 3, 45, dtype=F64)
LONG = torch.linspace(0, 10, 151, dtype=F64)


class Rescaled(HamiltonianSystem):
    """``base`` in the momenta ``p' = c·p``: ``H'(q, p') = c·H(q, p'/c)``. Then
    ``q̇ = ∂H'/∂p' = ∂H/∂p`` and ``ṗ' = −c·∂H/∂q = c·ṗ``: the same motion of ``q``, a
    gauge that positions cannot tell apart from ``base``."""

    def __init__(self, base: HamiltonianSystem, c: float) -> None:
        self.base, self.c, self.dof = base, c, base.dof

    def hamiltonian(self, y: Tensor) -> Tensor:
        q, p = y.chunk(2, -1)
        return self.c * self.base.hamiltonian(torch.cat([q, p / self.c], -1))

    def vector_field(self, t, y: Tensor) -> Tensor:
        """``(q̇, ṗ') = (f_q, c·f_p)(q, p'/c)``, the autograd default's closed form."""
        q, p = y.chunk(2, -1)
        dq, dp = self.base.vector_field(t, torch.cat([q, p / self.c], -1)).chunk(2, -1)
        return torch.cat([dq, self.c * dp], -1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        q, p = self.base.sample_initial(n, generator).chunk(2, -1)
        return torch.cat([q, self.c * p], -1)


class ModuleField(nn.Module):
    """A system's field as a module with a float32 parameter (a float32 model's dtype);
    records the dtype it is evaluated in."""

    def __init__(self, system: HamiltonianSystem) -> None:
        super().__init__()
        self.system = system
        self.unit = nn.Parameter(torch.ones((), dtype=torch.float32))
        self.seen: set[torch.dtype] = set()

    def vector_field(self, t, y: Tensor) -> Tensor:
        self.seen.add(y.dtype)
        return self.unit * self.system.vector_field(t, y)


def positions(system: HamiltonianSystem, y0: Tensor, t: Tensor) -> Tensor:
    """True positions ``(B, M, k)`` of the rows of ``y0`` at ``t (M,)``."""
    return system.trajectory(y0, t)[..., : system.dof].transpose(0, 1)


def starts(system: HamiltonianSystem, n: int = 25, seed: int = 0) -> Tensor:
    return system.sample_initial(n, torch.Generator().manual_seed(seed))


def noisy(q: Tensor, sigma: float, seed: int) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    return q + sigma * torch.randn(q.shape, generator=g, dtype=F64)


def rollout(field, y0: Tensor, t: Tensor = LONG) -> Tensor:
    """``(T, B, 2k)``: fixed steps of 0.01, the same for every field compared."""
    return odeint(field.vector_field, y0, t, method="rk4", step_size=0.01)


# ---------------------------------------------------------------------------- observer


@pytest.mark.parametrize("system", [Pendulum(), MassSpring()], ids=["pendulum", "spring"])
@pytest.mark.parametrize("dtype", ["float64", "model"], ids=["float64-copy", "float32"])
def test_recovers_the_exact_start_from_15_noise_free_positions(system, dtype):
    y0 = starts(system)
    field = ModuleField(system)
    o = observe(field, GRID[:15], positions(system, y0, GRID[:15]), dtype=dtype)
    assert field.seen == (set() if dtype == "float64" else {torch.float32})  # else: a copy
    assert field.unit.dtype == torch.float32
    assert o.y0.dtype == F64 and (o.status == ObserverStatus.OK).all()
    assert (o.y0 - y0).abs().max() < 1e-4
    assert o.rms.max() < 1e-5


def test_the_system_itself_is_a_field_and_infer_starts_returns_the_starts():
    system = Pendulum()
    y0 = starts(system, 6)
    q = positions(system, y0, GRID[:15])
    assert torch.equal(infer_starts(system, GRID[:15], q), observe(system, GRID[:15], q).y0)
    assert (infer_starts(system, GRID[:15], q) - y0).abs().max() < 1e-5


def test_fifteen_noisy_samples_fix_the_start_and_five_do_not():
    """σ = 0.1 on the angle, 100 starts: from the first second (15 samples) the true
    field's rollout to t = 10 keeps the typical trajectory's angle MSE at the noise's
    σ² (a few near the separatrix go over the top: the mean is larger); from 5 samples
    the velocity is not determined, and both the mean and the median are many times
    worse. (Over other draws the ratios run 9-200 for the mean, 10-28 for the median.)"""
    system = Pendulum()
    y0 = starts(system, 100, seed=10)
    truth = system.trajectory(y0, LONG)[..., 0]
    q = noisy(positions(system, y0, GRID[:15]), 0.1, seed=20)
    per_row = {}
    for m in (15, 5):
        o = observe(system, GRID[:m], q[:, :m])
        assert o.ok.all()
        per_row[m] = ((rollout(system, o.y0)[..., 0] - truth) ** 2).mean(0)
    assert per_row[15].median() < 3 * 0.1**2 and per_row[15].mean() < 0.25
    assert per_row[5].median() > 5 * per_row[15].median()
    assert per_row[5].mean() > 5 * per_row[15].mean()


@pytest.mark.parametrize("c", [1e3, 1e-3])
def test_the_fields_own_momentum_makes_the_start_blind_to_the_gauge(c):
    """Velocities become momenta through the field's own ``q̇ = ∂H/∂p``: under a gauge
    of ``p → 10³·p`` or ``10⁻³·p`` two Levenberg–Marquardt iterations already land on
    the start (assuming ``p = q̇`` instead leaves it off by 0.03 to 25)."""
    base = Pendulum()
    y0 = starts(base, 25, seed=6)
    o = observe(Rescaled(base, c), GRID[:15], positions(base, y0, GRID[:15]), iters=2)
    assert (o.y0[:, 0] - y0[:, 0]).abs().max() < 1e-4
    assert (o.y0[:, 1] / c - y0[:, 1]).abs().max() < 1e-4


def test_uneven_times_per_row():
    system = Pendulum()
    y0 = starts(system, 8)
    g = torch.Generator().manual_seed(3)
    jitter = (torch.rand(8, 15, generator=g, dtype=F64) - 0.5) * 0.6 * GRID[1]
    jitter[:, 0] = 0.0
    t = torch.rand(8, 1, generator=g, dtype=F64) + GRID[:15] + jitter  # own start, spacing
    q = torch.stack([positions(system, y0[b : b + 1], t[b])[0] for b in range(8)])
    o = observe(system, t, q)
    assert (o.status == ObserverStatus.OK).all()
    assert (o.y0 - y0).abs().max() < 1e-4  # each row's state at its own first time


def test_a_momentum_bound_holds_every_start_inside_it_and_costs_nothing_within():
    """``p_bound``: starts whose momenta lie inside it are recovered as without it;
    the others end on the bound (never outside), where the search was clipped."""
    system = MassSpring()
    y0 = starts(system, 25, seed=4)
    q = positions(system, y0, GRID[:15])
    b = 0.8 * y0[:, 1].abs().max()
    o = observe(system, GRID[:15], q, p_bound=b)
    assert (o.y0[:, 1].abs() <= b * (1 + 1e-12)).all()
    inside = y0[:, 1].abs() < 0.9 * b
    assert 0 < int(inside.sum()) < 25
    assert (o.y0[inside] - y0[inside]).abs().max() < 1e-4
    outside = y0[:, 1].abs() > b
    assert torch.allclose(o.y0[outside, 1].abs(), b.expand(int(outside.sum())))
    with pytest.raises(ValueError, match="p_bound"):
        observe(system, GRID[:15], q, p_bound=0.0)


def test_the_training_momentum_bound_is_the_models_own_states_else_its_data():
    """1.5 × the largest ``|p_i|`` the model was trained on: its learned states (in its
    own gauge) when it holds them, else the training states of states data; nothing
    for a system or for positions alone without learned states."""
    from types import SimpleNamespace

    from hnn_pl.evaluation.observer import MOMENTUM_BOUND, training_momentum_bound

    model = HNN(input_dim=2, hidden_dim=8)
    x = torch.tensor([[0.1, -2.0], [0.3, 1.0]])
    states_dm = SimpleNamespace(observe="states", x_train=x)
    assert torch.allclose(
        training_momentum_bound(model, states_dm), MOMENTUM_BOUND * 2.0 * torch.ones(1, dtype=F64)
    )
    assert training_momentum_bound(model, SimpleNamespace(observe="positions")) is None
    model.states = nn.Parameter(torch.tensor([[0.0, 0.5], [1.0, -0.25]]))
    assert torch.allclose(
        training_momentum_bound(model, states_dm), torch.tensor([0.75], dtype=F64)
    )
    assert training_momentum_bound(MassSpring(), states_dm) is None


class Frozen(nn.Module):
    """``q̇ = 0``: the momenta do not move the positions (a singular Newton Jacobian)."""

    def vector_field(self, t, y: Tensor) -> Tensor:
        q, _ = y.chunk(2, -1)
        return torch.cat([torch.zeros_like(q), -q], -1)


class Explosive(nn.Module):
    """``q̈ = 10⁴ q³``: every rollout over a second blows up."""

    def vector_field(self, t, y: Tensor) -> Tensor:
        q, p = y.chunk(2, -1)
        return torch.cat([p, 1e4 * q**3], -1)


def test_bad_rows_and_bad_fields_give_a_status_never_an_exception():
    system = Pendulum()
    y0 = starts(system, 6)
    t = GRID[:15].expand(6, -1).clone()
    q = positions(system, y0, GRID[:15]).clone()
    q[1, 4] = float("nan")
    t[2, 7] = t[2, 5]  # time goes back
    t[3, 9] = float("inf")
    o = observe(system, t, q)
    assert o.status.tolist() == [0, 2, 2, 2, 0, 0]
    assert o.y0[1:4].isnan().all() and o.rms[1:4].isnan().all()
    assert (o.y0[[0, 4, 5]] - y0[[0, 4, 5]]).abs().max() < 1e-4

    clean = positions(system, y0, GRID[:15])
    frozen = observe(Frozen(), GRID[:15], clean)
    assert torch.isfinite(frozen.y0).all() and frozen.ok.all()
    exploded = observe(Explosive(), GRID[:15], clean + 1.0)
    assert (exploded.status == ObserverStatus.DIVERGED).all()
    assert torch.isfinite(exploded.y0).all() and exploded.rms.isnan().all()


def test_a_float32_model_under_inference_mode_needs_no_gradients():
    torch.manual_seed(0)
    model = HNN(input_dim=2, hidden_dim=16)
    system = Pendulum()
    q = noisy(positions(system, starts(system, 4), GRID[:15]), 0.1, seed=4)
    with torch.inference_mode():
        a = observe(model, GRID[:15], q, iters=3)
        in_float32 = observe(model, GRID[:15], q.float(), iters=3, dtype="model")
    b = observe(model.field, GRID[:15], q, iters=3)
    assert torch.equal(a.y0, b.y0)  # a model is read through its .field
    assert torch.isfinite(a.y0).all() and a.y0.dtype == F64
    assert torch.isfinite(in_float32.y0).all() and in_float32.y0.dtype == F64
    assert next(model.parameters()).dtype == torch.float32
    assert all(p.grad is None for p in model.parameters())


# ----------------------------------------------------------------------------- metrics


@pytest.mark.parametrize(
    "system",
    [MassSpring(), Pendulum(), TwoBody(), ThreeBody(), Rescaled(Pendulum(), 2.5)],
    ids=["spring", "pendulum", "two-body", "three-body", "rescaled"],
)
def test_momentum_qv_inverts_the_velocity_of_vector_field(system):
    g = torch.Generator().manual_seed(5)
    y = system.sample_initial(12, g)
    y = y * (1 + 0.1 * torch.randn(y.shape, generator=g, dtype=F64))
    y = y.reshape(3, 4, -1)
    k = system.dof
    q, p = y[..., :k], y[..., k:]
    v = system.vector_field(None, y.reshape(12, -1)).reshape(y.shape)[..., :k]
    torch.testing.assert_close(system.momentum_qv(q, v), p, rtol=0, atol=1e-10)
    by_autograd = HamiltonianSystem.momentum_qv(system, q, v)
    torch.testing.assert_close(by_autograd, p, rtol=0, atol=1e-10)
    torch.testing.assert_close(system.energy_qv(q, v), system.energy(y), rtol=0, atol=1e-10)


@pytest.mark.parametrize("c", [2.5, 0.3])
@pytest.mark.parametrize("base", [Pendulum(), MassSpring()], ids=["pendulum", "spring"])
def test_metrics_and_observer_are_gauge_invariant(base, c):
    """The same noisy positions seen through ``base`` and through ``p → c·p, H → c·H``:
    the inferred starts differ by exactly that change, and the position MSE, the true
    energy from ``(q, q̇)`` and the valid time on positions are the same."""
    other = Rescaled(base, c)
    y0 = starts(base, 10, seed=6)
    truth = base.trajectory(y0, LONG)
    e_true = base.energy(truth)
    q = noisy(positions(base, y0, GRID[:15]), 0.1, seed=7)
    a, b = observe(base, GRID[:15], q), observe(other, GRID[:15], q)
    torch.testing.assert_close(b.y0[:, 0], a.y0[:, 0], rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(b.y0[:, 1], c * a.y0[:, 1], rtol=1e-6, atol=1e-7)

    scaled = torch.stack([a.y0[:, 0], c * a.y0[:, 1]], -1)
    pa, pb = rollout(base, a.y0), rollout(other, scaled)
    assert abs(float(position_mse(pa, truth, 1) - position_mse(pb, truth, 1))) < 1e-10
    va = velocity_energy_mse(base, base, pa, e_true)
    vb = velocity_energy_mse(base, other, pb, e_true)
    assert abs(float(va - vb)) < 1e-10
    torch.testing.assert_close(
        position_valid_time(LONG, pa, truth, 1), position_valid_time(LONG, pb, truth, 1)
    )
    # end to end, each model's own inferred start
    pb_inferred = rollout(other, b.y0)
    assert position_mse(pb_inferred, truth, 1) == pytest.approx(
        float(position_mse(pa, truth, 1)), rel=1e-7
    )
    assert velocity_energy_mse(base, other, pb_inferred, e_true) == pytest.approx(
        float(va), rel=1e-7
    )


def test_position_mse_leaves_out_unobserved_truth_but_not_a_failed_prediction():
    truth = torch.arange(24, dtype=F64).reshape(3, 4, 2)
    pred = truth.clone()
    pred[..., 0] += 1.0
    pred[0, 0, 0] += 2.0  # error 3 where the truth is unobserved
    truth_missing = truth.clone()
    truth_missing[0, 0] = float("nan")
    assert float(position_mse(pred, truth, 1)) == pytest.approx((11 + 9) / 12)
    assert float(position_mse(pred, truth_missing, 1)) == 1.0
    pred[1, 1, 0] = float("nan")
    assert position_mse(pred, truth_missing, 1).isnan()
    assert float(position_mse(pred[..., 1:], truth[..., 1:], 1)) == 0.0  # k picks columns


def test_velocity_energy_of_the_true_field_is_the_true_energy():
    system = Pendulum()
    y = rollout(system, starts(system, 5))
    torch.testing.assert_close(velocity_energy(system, system, y), system.energy(y))
    e_true = system.energy(y)
    e_true[3:, 0] = float("nan")  # unobserved: left out
    assert float(velocity_energy_mse(system, system, y, e_true)) < 1e-24
    # a field at half the true speed reads (q, q̇/2): E = α(1 − cos q) + β (p/2)²
    half = ModuleField(system)
    with torch.no_grad():
        half.unit.fill_(0.5)
    q, p = y.unbind(-1)
    expected = system.alpha * (1 - torch.cos(q)) + system.beta * (p / 2) ** 2
    torch.testing.assert_close(velocity_energy(system, half, y), expected)


def test_position_valid_time_reads_positions_only():
    t = torch.linspace(0, 1, 11, dtype=F64)
    truth = torch.ones(11, 2, 2, dtype=F64)
    pred = truth.clone()
    pred[..., 1] += 5.0  # a wrong momentum does not count
    pred[6:, 1, 0] += 1.0  # row 1's position leaves at t = 0.6
    assert position_valid_time(t, pred, truth, 1).tolist() == pytest.approx([1.0, 0.6])
    assert torch.equal(valid_time_of(t, pred, truth)[1], t[0])
