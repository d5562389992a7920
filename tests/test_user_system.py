"""A system given by H alone (examples/double_well.py) trains through the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from hnn_pl import evaluation
from hnn_pl.commands.cli import cli_main
from hnn_pl.experiments import paper

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def double_well(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))
    from double_well import DoubleWell

    return DoubleWell


def test_the_vector_field_is_J_grad_H_by_autograd(double_well):
    y = torch.randn(7, 2, dtype=torch.float64)
    q, p = y[:, 0], y[:, 1]
    expected = torch.stack([p, -(q**3 - q)], -1)
    torch.testing.assert_close(double_well().vector_field(None, y), expected)
    with torch.inference_mode():
        torch.testing.assert_close(double_well().vector_field(None, y), expected)


@pytest.mark.slow
def test_a_system_from_h_alone_trains_and_the_hnn_beats_its_baseline(double_well, tmp_path):
    energy = {}
    for name in ("hnn", "baseline"):
        config = paper.get("spring").config(name, "fast")
        args = [
            f"--config={config}",
            "--data.init_args.system=double_well.DoubleWell",
            "--seed_everything=0",
            "--trainer.logger=false",
            "--trainer.enable_checkpointing=false",
            "--trainer.enable_progress_bar=false",
            "--trainer.callbacks=[]",
            f"--trainer.default_root_dir={tmp_path}",
        ]
        cli = cli_main(args, run=False, save_config=False)
        assert type(cli.datamodule.system) is double_well
        cli.trainer.fit(cli.model, cli.datamodule)
        assert "double_well.DoubleWell" in str(cli.datamodule.cache_params()["system"])
        metrics, _ = evaluation.evaluate(
            cli.model, cli.datamodule, evaluation.task_protocol("spring", "clean")
        )
        energy[name] = metrics["energy_mse"]
    assert energy["hnn"] < energy["baseline"] / 3, energy
