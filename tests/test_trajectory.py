"""The trajectory objective: windows of observed states, integrated and compared."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from hnn_pl import HNN, Baseline, DissipativeHNN, evaluation
from hnn_pl.commands.cli import QUIET_TRAINER
from hnn_pl.integrate import WINDOW_METHODS, odeint_windows
from hnn_pl.models.base import DynamicsModel
from hnn_pl.nets import DirectField

F64 = torch.float64


class LinearModel(DynamicsModel):
    """``dy/dt = A y`` with a learnable ``A``: the field the hand computations use."""

    def build_field(self, input_dim, hidden_dim, n_hidden, activation):
        return DirectField(nn.Linear(input_dim, input_dim, bias=False))


def _windows(B=6, K=4, D=2, seed=0):
    """Hand-made windows: random states, unevenly spaced increasing times, indices."""
    g = torch.Generator().manual_seed(seed)
    y = torch.randn(B, K, D, generator=g, dtype=F64)
    t = torch.cumsum(0.05 + 0.3 * torch.rand(B, K, generator=g, dtype=F64), 1)
    index = torch.arange(B * K).reshape(B, K)
    return y, t, index


def _rk4_matrix(A, h):
    """One RK4 step of ``dy/dt = A y``: ``Σ_{j≤4} (hA)^j / j!``."""
    P, term = torch.eye(A.shape[0], dtype=F64), torch.eye(A.shape[0], dtype=F64)
    for j in range(1, 5):
        term = term @ (h * A) / j
        P = P + term
    return P


@pytest.mark.parametrize("learned, continuity", [("none", 0), ("sample", 0), ("sample", 0.3)])
def test_window_loss_equals_hand_computed_on_linear_field(learned, continuity):
    torch.manual_seed(0)
    y, t, index = _windows()
    model = LinearModel(objective="trajectory", substeps=2, learned_states=learned)
    model = model.double()
    model.state_weight, model.continuity_weight = 0.7, continuity
    obs = y.reshape(-1, 2) + 0.01
    model.init_states(obs, t.reshape(-1), torch.arange(len(obs)) // 4)
    A = model.field.net.weight.detach()
    loss = 0.0
    for b in range(y.shape[0]):
        state = obs[index[b, 0]] if learned == "sample" else y[b, 0]
        z0 = state
        for k in range(1, y.shape[1]):
            step = _rk4_matrix(A, float(t[b, k] - t[b, k - 1]) / 2)
            state = step @ step @ state
            loss += float(((state - y[b, k]) ** 2).sum())
            loss += continuity * float(((state - obs[index[b, k]]) ** 2).sum())
        if learned == "sample":
            loss += 0.7 * float(((z0 - y[b, 0]) ** 2).sum()) * (y.shape[1] - 1)
    loss /= y.shape[0] * (y.shape[1] - 1) * y.shape[2]
    got = model.training_loss((y, t, index))["loss"]
    assert math.isclose(float(got.detach()), loss, rel_tol=1e-12)


def test_continuity_needs_per_sample_states():
    with pytest.raises(ValueError, match="continuity_weight .* only with learned_states: sample"):
        HNN(objective="trajectory", learned_states="trajectory", continuity_weight=1.0)


class _Loss(nn.Module):
    """A model's training loss as a module's output, for ``torch.func.functional_call``."""

    def __init__(self, model: DynamicsModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, batch):
        return self.model.training_loss(batch)["loss"]


@pytest.mark.parametrize("method", ["rk4", "leapfrog", "implicit_midpoint"])
@pytest.mark.parametrize("cls", [HNN, DissipativeHNN])
def test_window_loss_gradient_matches_finite_differences(method, cls):
    """gradcheck (float64) of the loss in the field's last layer and in the learned
    per-trajectory states (so the lead-in from each trajectory's start is covered)."""
    torch.manual_seed(1)
    y, t, index = _windows(B=4, K=3)
    index = torch.tensor([[0, 1, 2], [1, 2, 3], [5, 6, 7], [6, 7, 8]])
    model = cls(hidden_dim=8, objective="trajectory", traj_method=method, substeps=2)
    model.learned_states = "trajectory"
    model = model.double().train()
    model.init_states(
        torch.randn(9, 2, dtype=F64),
        torch.arange(9.0, dtype=F64) / 4,
        torch.tensor([0, 0, 0, 0, 0, 1, 1, 1, 1]),
    )
    t = model.obs_t_train[index]
    loss = _Loss(model)

    def f(w, states):
        return torch.func.functional_call(
            loss, {"model.field.net.out.weight": w, "model.states": states}, ((y, t, index),)
        )

    w0 = model.field.net.out.weight.detach().clone().requires_grad_(True)
    s0 = model.states.detach().clone().requires_grad_(True)
    atol = 1e-5 if method == "implicit_midpoint" else 1e-8
    assert torch.autograd.gradcheck(f, (w0, s0), eps=1e-6, atol=atol, rtol=1e-4)


def test_uneven_spacing_is_integrated_exactly_for_a_linear_field():
    """Rows with their own uneven times against the matrix exponential (float64):
    RK4's error falls as h⁴ to the solution, implicit midpoint's as h²."""
    A = torch.tensor([[0.0, 1.3], [-0.8, -0.1]], dtype=F64)
    y, t, _ = _windows(B=5, K=6)
    y0 = y[:, 0]
    exact = torch.stack(
        [
            torch.stack([torch.linalg.matrix_exp(A * (tk - t[b, 0])) @ y0[b] for tk in t[b]])
            for b in range(5)
        ]
    )

    def error(method, substeps):
        out = odeint_windows(lambda s, x: x @ A.T, y0, t, method, substeps, 1e-13, 1e-13)
        assert out.shape == (5, 6, 2) and torch.equal(out[:, 0], y0)
        return float((out - exact).abs().max())

    assert error("rk4", 40) < 1e-10
    assert 12 < error("rk4", 10) / error("rk4", 20) < 20
    assert error("implicit_midpoint", 400) < 1e-5
    assert 3.5 < error("implicit_midpoint", 50) / error("implicit_midpoint", 100) < 4.5
    assert set(WINDOW_METHODS) >= {"rk4", "leapfrog", "implicit_midpoint"}


def test_wrong_batch_kind_fails_in_one_line():
    y, t, index = _windows()
    pairs = (y[:, 0], y[:, 1])
    derivative = Baseline(objective="derivative")
    for model, batch in [(HNN(objective="trajectory"), pairs), (derivative, (y, t, index))]:
        with pytest.raises(ValueError) as err:
            model.training_loss(batch)
        assert "\n" not in str(err.value) and "objective" in str(err.value)
    with pytest.raises(ValueError, match="traj_method"):
        HNN(objective="trajectory", traj_method="dopri5")


def test_learned_states_have_no_weight_decay_and_survive_a_checkpoint(tmp_path):
    y, t, index = _windows()
    model = HNN(objective="trajectory", learned_states="trajectory", weight_decay=1e-4)
    model.init_states(y.reshape(-1, 2).float(), t.reshape(-1).float(), torch.arange(24) // 4)
    groups = model.param_groups()
    assert groups[-1]["params"] == [model.states] and groups[-1]["weight_decay"] == 0.0
    assert model.states.shape == (6, 2)
    model.states.data += 1.0
    path = tmp_path / "m.ckpt"
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}, path)
    fresh = HNN(objective="trajectory", learned_states="trajectory")
    ckpt = torch.load(path, weights_only=True)
    fresh.on_load_checkpoint(ckpt)
    fresh.load_state_dict(ckpt["state_dict"])
    torch.testing.assert_close(fresh.states, model.states)


def _spring(window=None, **kwargs):
    from hnn_pl.data import SimulatedData
    from hnn_pl.systems import MassSpring

    return SimulatedData(
        system=MassSpring(),
        n_trajectories=50,
        t_span=(0.0, 3.0),
        n_points=30,
        noise_std=0.1,
        seed=0,
        window=window,
        **kwargs,
    )


def _fit(model, dm, steps):
    import lightning as L

    trainer = L.Trainer(max_steps=steps, inference_mode=False, **QUIET_TRAINER)
    trainer.fit(model, dm)
    return trainer


@pytest.mark.slow
def test_states_only_spring_fit_learns_the_dynamics():
    """The paper's noisy spring states (σ = 0.1), derivatives withheld, 150 steps: the
    trajectory objective's HNN against the same HNN regressed on central differences
    of the same states (the fast recipe), both scored in the true energy (the
    independent evaluation; an untrained HNN scores ≈ 10). Measured here: 2.6e-3
    against 2.9e-3 — central differences are not hopeless at this noise with a short
    recipe, so the issue's ≥ 10× is not met (BENCHMARKS.md)."""
    from hnn_pl.data.differences import central_differences

    torch.manual_seed(0)
    protocol = evaluation.task_protocol("spring", "independent")
    dm = _spring(window=5, batch_size=128)
    traj = HNN(objective="trajectory", learned_states="sample", lr=3e-3, schedule="onecycle")
    trainer = _fit(traj, dm, 150)
    assert trainer.global_step == 150 and traj.states.shape == (750, 2)
    torch.manual_seed(0)
    dm_c = _spring(full_batch_steps=10)
    dm_c.setup("fit")
    dm_c.dx_train = central_differences(dm_c.obs_y_train, dm_c.obs_t_train, dm_c.obs_traj_train)
    central = HNN(lr=3e-3, schedule="onecycle", inner_steps=10, weight_decay=1e-4)
    _fit(central, dm_c, 150)
    e_traj = evaluation.evaluate(traj, dm, protocol)[0]["energy_mse"]
    e_central = evaluation.evaluate(central, dm_c, protocol)[0]["energy_mse"]
    assert e_traj <= 5e-3 and e_traj <= e_central, (e_traj, e_central)
