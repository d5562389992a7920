"""Long-horizon metrics and the error split: valid prediction time, energy drift, and
the integrator and chaos floors below a trained model's error."""

from __future__ import annotations

import math

import pytest
import torch

from hnn_pl import evaluation
from hnn_pl.commands.cli import cli_main


def _circle(t: torch.Tensor, omega: float) -> torch.Tensor:
    return torch.stack([torch.cos(omega * t), -torch.sin(omega * t)], -1)[:, None]


def test_valid_time_is_the_first_crossing_of_the_normalised_error():
    """Unit circle at ω = 1 against ω = 1.01: |Δy| = 2 |sin(0.005 t)| first passes
    0.025 at t = 2 asin(0.0125) / 0.01."""
    t = torch.linspace(0, 20, 20001, dtype=torch.float64)
    y_true, y_pred = _circle(t, 1.0), _circle(t, 1.01)
    e = (y_true**2).sum(-1)
    r = evaluation.Rollout(t, y_true, y_pred, e, e)
    expected = 2 * math.asin(0.0125) / 0.01
    assert float(evaluation.metrics.valid_time(r)[0]) == pytest.approx(expected, abs=2e-3)
    never = evaluation.Rollout(t, y_true, y_true.clone(), e, e)
    assert float(evaluation.metrics.valid_time(never)[0]) == 20.0


def test_energy_drift_slope_of_a_linear_drift():
    t = torch.linspace(0, 10, 101, dtype=torch.float64)
    e_true = torch.full((101, 3), 2.0, dtype=torch.float64)
    e_pred = e_true * (1 + 1e-3 * t[:, None])
    y = torch.zeros(101, 3, 2, dtype=torch.float64)
    r = evaluation.Rollout(t, y, y, e_true, e_pred)
    assert float(evaluation.metrics.energy_drift_slope(r)) == pytest.approx(1e-3, rel=1e-9)


def test_the_floors_lie_below_a_trained_models_error():
    args = [
        "--config=spring_fast.yaml",
        "--trainer.max_steps=150",
        "--trainer.logger=false",
        "--trainer.enable_checkpointing=false",
        "--trainer.enable_progress_bar=false",
        "--trainer.callbacks=[]",
    ]
    cli = cli_main(args, run=False, save_config=False)
    cli.trainer.fit(cli.model, cli.datamodule)
    clean = evaluation.task_protocol("spring", "clean")
    for protocol in (clean, clean.replace(method="rk4", step_size=0.1)):
        m, _ = evaluation.evaluate(cli.model, cli.datamodule, protocol)
        assert m["floor_chaos_energy_mse"] < m["energy_mse"] / 10, m
        assert m["floor_integrator_energy_mse"] < m["energy_mse"], m
        assert 0 < m["valid_time"] <= 20.0 and math.isfinite(m["energy_drift_slope"])
    assert m["floor_integrator_energy_mse"] > 1e-12  # rk4 at h = 0.1 has an error of its own
