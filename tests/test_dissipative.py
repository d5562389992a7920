"""The dissipative HNN: its field, friction against an analytic damped oscillator, and
the measured pendulum, on which its energy decays while the HNN's does not."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.integrate import solve_ivp
from torch import nn

from hnn_pl import evaluation, odeint
from hnn_pl.commands.cli import cli_main
from hnn_pl.data import RealPendulumData
from hnn_pl.nets import MLP, DissipativeField
from hnn_pl.systems.base import symplectic_gradient
from hnn_pl.systems.real_pendulum import load_real_pendulum

CLEAN = evaluation.task_protocol("real_pendulum", "clean")


class Quadratic(nn.Module):
    """``s(q, p) = a q² + b p²`` as a ``(batch, 1)`` output, a net without closed form."""

    def __init__(self, a: float, b: float) -> None:
        super().__init__()
        self.a, self.b = a, b

    def forward(self, y):
        return (self.a * y[..., :1] ** 2 + self.b * y[..., 1:] ** 2).reshape(*y.shape[:-1], 1)


@pytest.mark.parametrize("momentum_only", [True, False])
def test_field_is_symplectic_gradient_plus_projected_dissipation(momentum_only):
    torch.manual_seed(0)
    h, d = MLP(4, 1, 16).double(), MLP(4, 1, 16).double()
    field = DissipativeField(h, d, momentum_only=momentum_only)
    y = torch.randn(7, 4, dtype=torch.float64, requires_grad=True)
    (gh,) = torch.autograd.grad(h(y).sum(), y)
    (gd,) = torch.autograd.grad(d(y).sum(), y)
    if momentum_only:
        gd[:, :2] = 0
    expected = symplectic_gradient(gh) + gd
    got = field.vector_field(None, y.detach())
    torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)
    assert got.shape == (7, 4) and field.hamiltonian(y).shape == (7,)


def test_rayleigh_friction_is_the_damped_oscillator():
    """``H = q² + p²``, ``D = −c p²``: ``q̈ + 2c q̇ + 4q = 0`` — against scipy at 1e-12 and
    ``dH/dt = −4c p² ≤ 0``."""
    c = 0.1
    field = DissipativeField(Quadratic(1.0, 1.0), Quadratic(0.0, -c))
    y0 = torch.tensor([[1.0, 0.0], [0.3, -0.8]], dtype=torch.float64)
    t = torch.linspace(0, 10, 101, dtype=torch.float64)
    y = odeint(field.vector_field, y0, t, method="dopri5", rtol=1e-11, atol=1e-12)

    def f(_, z):
        q, p = z
        return [2 * p, -2 * q - 2 * c * p]

    for b in range(2):
        ref = solve_ivp(f, (0, 10), y0[b].numpy(), t_eval=t.numpy(), rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(y[:, b], torch.from_numpy(ref.y.T), rtol=0, atol=1e-9)
    energy = (y**2).sum(-1)
    assert (energy[1:] <= energy[:-1] + 1e-12).all()
    assert energy[-1, 0] < 0.2 * energy[0, 0]


def _fit(config: str, tmp_path, *extra: str):
    args = [f"--config={config}", "--seed_everything=0", "--trainer.logger=false"]
    args += ["--trainer.enable_checkpointing=false", "--trainer.enable_progress_bar=false"]
    args += ["--trainer.callbacks=[]", f"--data.init_args.cache_dir={tmp_path}", *extra]
    cli = cli_main(args, run=False, save_config=False)
    cli.trainer.fit(cli.model, cli.datamodule)
    return cli


@pytest.mark.slow
def test_energy_decays_for_the_dissipative_hnn_and_not_for_the_hnn(tmp_path):
    """The measured pendulum, fast recipes: the dissipative model's rollout of the
    held-out segment loses energy and ``H_θ``; the HNN's keeps both. (Two fits judged on
    their results: the slow tier. The field's decay is in the default tier:
    ``test_rayleigh_friction_is_the_damped_oscillator``.)"""
    out = {}
    for name in ("real_pendulum_fast_dissipative.yaml", "real_pendulum_fast.yaml"):
        cli = _fit(name, tmp_path)
        metrics, r = evaluation.evaluate(cli.model, cli.datamodule, CLEAN)
        out[name] = metrics, r
    (m_d, r_d), (m_h, r_h) = out.values()
    assert m_d["true_energy_drift_slope"] < -0.005
    assert m_d["energy_drift_slope"] < -0.005
    assert (r_d.h_pred[-1] < r_d.h_pred[0] - 0.05 * r_d.h_scale).all()
    assert abs(m_h["energy_drift_slope"]) < 1e-3
    assert m_h["conserved_drift"] < 1e-6


def test_central_differences_are_centred_on_the_measured_samples(tmp_path):
    dm = RealPendulumData(cache_dir=str(tmp_path), dtype="float64", differences="central")
    dm.setup()
    t, y = load_real_pendulum()
    assert dm.x_train.shape == (444, 2) and dm.x_test.shape == (110, 2)
    torch.testing.assert_close(dm.x_test, y[445:555])
    torch.testing.assert_close(dm.dx_test[0], (y[446] - y[444]) / (t[446] - t[444]))


@pytest.mark.slow
def test_central_differences_carry_the_measured_decay(tmp_path):
    """Forward differences read as extra friction; on central differences the
    dissipative model's energy slope lands near the measured one (a fit judged on its
    result: the slow tier)."""
    cli = _fit("real_pendulum_fast_dissipative.yaml", tmp_path, "--data.differences=central")
    metrics, _ = evaluation.evaluate(cli.model, cli.datamodule, CLEAN)
    ratio = metrics["energy_drift_slope"] / metrics["true_energy_drift_slope"]
    assert 0.4 < ratio < 2.5, metrics
    assert math.isfinite(metrics["energy_mse"])
