"""Energy bump: H_θ changes by the requested amount, then stays there."""

from __future__ import annotations

import copy
import shutil

import pytest
import torch

from hnn_pl.bump import energy_bump
from hnn_pl.models import HNN, AutoencoderHNN, Baseline


@pytest.mark.parametrize("fraction", [0.1, -0.1])
def test_the_bump_moves_h_by_delta_and_the_rollout_keeps_it(fraction):
    """Bumps of a tenth of H_θ's spread over the starts (an untrained H_θ is bounded
    and has critical points, where the gradient flow is singular)."""
    torch.manual_seed(0)
    model = HNN(input_dim=2, hidden_dim=32)
    y0 = 0.5 * torch.randn(6, 2)
    with torch.no_grad():
        h0 = copy.deepcopy(model.field).double().hamiltonian(y0.double())
    delta = fraction * float(h0.max() - h0.min())
    z1, out = energy_bump(model, y0, delta, torch.linspace(0, 5, 51, dtype=torch.float64))
    torch.testing.assert_close(out.h_pred[0], h0 + delta, rtol=0, atol=1e-7)
    assert (out.h_pred - out.h_pred[:1]).abs().max() < 1e-7
    assert torch.equal(out.y_pred[0], z1) and (z1 - y0.double()).abs().max() > 0


def test_a_pixel_model_is_bumped_in_its_latent_space_and_decoded():
    torch.manual_seed(0)
    model = AutoencoderHNN(input_dim=1568)
    x0 = torch.rand(3, 1568)
    with torch.no_grad():
        h0 = copy.deepcopy(model.field).double().hamiltonian(model.encode(x0).double())
    _, out = energy_bump(model, x0, 0.01, torch.linspace(0, 1, 11, dtype=torch.float64))
    torch.testing.assert_close(out.h_pred[0], h0 + 0.01, rtol=0, atol=1e-7)
    assert out.x_pred.shape == (11, 3, 1568) and torch.isfinite(out.x_pred).all()


def test_a_model_without_h_cannot_be_bumped():
    with pytest.raises(ValueError, match="only HNN"):
        energy_bump(Baseline(input_dim=2), torch.zeros(1, 2), 0.1, torch.linspace(0, 1, 3))


def test_a_bump_past_the_range_of_h_says_so():
    torch.manual_seed(0)
    model = HNN(input_dim=2, hidden_dim=32)
    with pytest.raises(ValueError, match="critical point of H_θ"):
        energy_bump(model, 0.5 * torch.randn(6, 2), 100.0, torch.linspace(0, 1, 3))


def test_the_bump_command_writes_the_rollouts_and_a_figure(tmp_path, monkeypatch):
    from hnn_pl.commands.main import main

    monkeypatch.chdir(tmp_path)
    fit = [
        "fit",
        "--config",
        "spring_fast.yaml",
        "--trainer.max_steps=30",
        "--trainer.logger=false",
    ]
    main([*fit, "--trainer.default_root_dir", str(tmp_path / "run")])
    (ckpt,) = (tmp_path / "run").rglob("last.ckpt")
    argv = ["bump", "--config", "spring_fast.yaml", "--ckpt_path", str(ckpt), "--out", "b"]
    with pytest.raises(SystemExit) as info:
        main([*argv, "--t_end", "2", "--n_points", "21"])
    assert info.value.code == 0
    saved = torch.load(tmp_path / "b" / "bump.pt", weights_only=True)
    moved = saved["after"]["h"][0] - saved["before"]["h"][0]
    torch.testing.assert_close(moved, torch.full_like(moved, saved["delta"]), rtol=0, atol=1e-7)
    assert (tmp_path / "b" / "bump.png").stat().st_size > 10_000
    h0 = saved["before"]["h"][0]
    default = 0.2 * float(h0.max() - h0.min() + h0.abs().mean())
    assert saved["delta"] == pytest.approx(default, rel=1e-12, abs=0)  # as --help says
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(ckpt, alone / "m.ckpt")
    argv = ["bump", "--config", "spring_fast.yaml", "--ckpt_path", str(alone / "m.ckpt")]
    with pytest.raises(SystemExit) as info:
        main([*argv, "--t_end", "1", "--n_points", "5", "--starts", "1"])
    assert info.value.code == 0 and (alone / "bump.pt").is_file()  # beside a loose checkpoint


def test_bump_help_gives_each_number_its_range_and_default(capsys):
    from hnn_pl.commands.bump import main

    with pytest.raises(SystemExit):
        main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "ΔH_θ, a finite number (default: 20 % of the spread of H_θ over the bumped" in text
    assert "0.2 (max H − min H + mean |H|)" in text
    assert "rollout horizon > 0 (default: 10)" in text and ">= 2 (default: 200)" in text
    assert "held-out starts to bump (default: 4)" in text
