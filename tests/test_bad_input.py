"""Bad input gets one clear line and exit status 2, before any file is written."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

from hnn_pl.commands import reproduce
from hnn_pl.commands.main import main


@pytest.fixture(autouse=True)
def _quiet_logging_errors(monkeypatch):
    """Lightning's log handlers keep the stderr of the test that imported it, which
    pytest has closed since: drop those write errors instead of printing them."""
    monkeypatch.setattr(logging, "raiseExceptions", False)


def _fails(argv, capsys, monkeypatch, tmp_path) -> str:
    """Run the CLI in ``tmp_path`` with a private cache; the one stderr line it printed."""
    monkeypatch.chdir(tmp_path)
    cache = tmp_path / "cache"
    monkeypatch.setenv("HNN_PL_CACHE", str(cache))
    monkeypatch.delenv("HNN_PL_TRACEBACK", raising=False)
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("python -m hnn_pl: error: "), err
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert written == [p for p in written if p.suffix == ".yaml"], "nothing may be written"
    assert not (tmp_path / "lightning_logs").exists() and not cache.exists()
    return err[0]


FIT = ["fit", "--config", "spring_fast.yaml", "--trainer.max_steps=2"]


@pytest.mark.parametrize(
    ("option", "expected"),
    [
        ("--data.init_args.noise_std=-1", "noise_std must be >= 0"),
        ("--data.init_args.n_trajectories=0", "n_trajectories must be >= 2"),
        ("--data.init_args.test_fraction=0", "test_fraction must lie in (0, 1)"),
        ("--data.init_args.test_fraction=1", "test_fraction must lie in (0, 1)"),
        ("--data.init_args.test_fraction=0.001", "holds out 0"),
        ("--data.init_args.batch_size=0", "batch_size must be >= 1"),
        ("--data.init_args.n_points=1", "n_points must be >= 2"),
        ("--model.init_args.hidden_dim=0", "hidden_dim"),
        ("--model.init_args.input_dim=4", "input_dim = 4"),
        ("--model.init_args.lr=.inf", "lr must be finite"),
        ("--threads=0", "threads must be >= 1"),
    ],
)
def test_bad_options_fail_at_once_with_one_line(option, expected, capsys, monkeypatch, tmp_path):
    line = _fails([*FIT, option], capsys, monkeypatch, tmp_path)
    assert expected in line


def test_a_bad_rollout_method_fails_before_training(capsys, monkeypatch, tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text(
        "trainer:\n  callbacks:\n    - class_path: hnn_pl.callbacks.RolloutCallback\n"
        "      init_args: {task: spring, overrides: {method: rk5}}\n"
    )
    line = _fails([*FIT, "--config", str(config)], capsys, monkeypatch, tmp_path)
    assert "unknown method 'rk5'" in line


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (os.urandom(2000), "not a text file"),
        (b"model: [1, 2\n", "not valid YAML at line 2"),
        (b"- just\n- a list\n", "expected a mapping"),
    ],
    ids=["random-bytes", "broken-yaml", "a-list"],
)
def test_a_bad_config_file_is_named(content, expected, capsys, monkeypatch, tmp_path):
    config = tmp_path / "bad.yaml"
    config.write_bytes(content)
    line = _fails(["fit", "--config", str(config)], capsys, monkeypatch, tmp_path)
    assert f"config {config}" in line and expected in line


def _two_step_checkpoint(config: str, root: Path) -> Path:
    """``last.ckpt`` of a 2-step ``fit`` of a bundled config under ``root``."""
    argv = ["fit", "--config", config, "--trainer.max_steps=2", "--trainer.logger=false"]
    main([*argv, "--trainer.default_root_dir", str(root)])
    (ckpt,) = root.rglob("last.ckpt")
    return ckpt


def _test_error_lines(capsys, ckpt: Path) -> list[str]:
    """``test --config spring_fast.yaml --ckpt_path ckpt`` must exit 2: its error lines."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["test", "--config", "spring_fast.yaml", "--ckpt_path", str(ckpt)])
    assert info.value.code == 2
    return [line for line in capsys.readouterr().err.splitlines() if "error:" in line]


def test_a_checkpoint_of_another_model_class_is_refused(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    ckpt = _two_step_checkpoint("spring_fast_baseline.yaml", tmp_path / "b")
    err = _test_error_lines(capsys, ckpt)
    assert len(err) == 1 and "hnn_pl.models.baseline.Baseline" in err[0]
    assert "builds a hnn_pl.models.HNN" in err[0] and str(ckpt) in err[0]


def test_reproduce_never_overwrites_results_by_default(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    Path("RESULTS.md").write_text("the committed results\n")
    argv = ["--tasks", "real_pendulum", "--models", "hnn", "--seeds", "1", "--workers", "0"]
    assert reproduce.main([*argv, "--max-steps", "2"]) == 0
    assert Path("RESULTS.md").read_text() == "the committed results\n"
    (written,) = Path("results").glob("paper-*/RESULTS.md")
    assert "real_pendulum" in written.read_text()


class _Payload:
    """Stands for anything a pickle could build (and run) beyond tensors."""


def test_a_checkpoint_that_is_more_than_weights_is_not_unpickled(capsys, monkeypatch, tmp_path):
    import torch

    monkeypatch.chdir(tmp_path)
    ckpt = _two_step_checkpoint("spring_fast.yaml", tmp_path / "h")
    payload = torch.load(ckpt, weights_only=True)
    payload["extra"] = _Payload()
    torch.save(payload, ckpt)
    err = _test_error_lines(capsys, ckpt)
    assert len(err) == 1 and "holds more than weights" in err[0] and "_Payload" in err[0]
    assert "weights_only" not in err[0]
