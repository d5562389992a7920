"""The command line end to end: a short fit of every config, test, checkpoints."""

from __future__ import annotations

import contextlib
import functools
import io
import itertools
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from hnn_pl.commands.cli import cli_main
from hnn_pl.commands.config_paths import (
    CONFIG_DIR,
    bundled_configs,
    config_chain,
    load_config_file,
    resolve_config,
)

CONFIGS = bundled_configs()


def _common(tmp_path: Path) -> list[str]:
    return [
        f"--trainer.default_root_dir={tmp_path}",
        f"--trainer.logger.init_args.save_dir={tmp_path}",
        f"--data.init_args.cache_dir={tmp_path / 'cache'}",
        "--trainer.enable_progress_bar=false",
        "--data.init_args.full_batch_steps=2",
    ]


def _fit(config: str, tmp_path: Path, steps: int = 4, extra: list[str] = ()):
    args = ["fit", "--config", config, f"--trainer.max_steps={steps}"]
    args += ["--trainer.check_val_every_n_epoch=1", "--trainer.val_check_interval=1.0"]
    args += ["--trainer.log_every_n_steps=1"]
    args += [
        "--trainer.limit_train_batches=2",
        "--model.init_args.inner_steps=2",
        *_common(tmp_path),
        *extra,
    ]
    return cli_main(args)


def _tags(log_dir: str) -> dict[str, list[str]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(log_dir, size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    return acc.Tags()


def test_a_command_builds_the_parser_of_its_own_subcommand_only(monkeypatch, capsys):
    """``validate …`` builds the validate parser alone; ``--help`` still lists all four."""
    from lightning.pytorch.cli import LightningCLI

    built, prepare = [], LightningCLI._prepare_subcommand_parser

    def record(self, klass, subcommand, **kwargs):
        built.append(subcommand)
        return prepare(self, klass, subcommand, **kwargs)

    monkeypatch.setattr(LightningCLI, "_prepare_subcommand_parser", record)
    out = _resolved_text("spring_fast.yaml")
    assert built == ["fit"] and "max_steps: 300" in out
    built.clear()
    with pytest.raises(SystemExit):
        cli_main(["validate", "--config", "spring_fast.yaml", "--print_config"])
    assert built == ["validate"] and "ckpt_path" in capsys.readouterr().out
    built.clear()
    with pytest.raises(SystemExit) as exit_:
        cli_main(["--help"])
    assert exit_.value.code == 0 and built == ["fit", "validate", "test", "predict"]
    assert "{fit,validate,test,predict}" in capsys.readouterr().out


def test_bare_config_names_resolve_to_the_bundled_dir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_config("spring.yaml") == str(CONFIG_DIR / "spring.yaml")
    assert resolve_config("spring") == str(CONFIG_DIR / "spring.yaml")
    (tmp_path / "spring.yaml").write_text("trainer: {}\n")
    assert resolve_config("spring.yaml") == "spring.yaml"
    with pytest.raises(FileNotFoundError, match="spring.yaml"):
        resolve_config("nonexistent.yaml")


def test_bundled_configs_are_the_package_hnn_pl_configs():
    from importlib.resources import files

    assert CONFIG_DIR == Path(str(files("hnn_pl.configs")))
    assert CONFIG_DIR.samefile(Path(__file__).resolve().parent.parent / "configs")
    assert "spring.yaml" in bundled_configs() and "__init__.py" not in bundled_configs()


def test_top_level_help_lists_commands_and_configs():
    out = subprocess.run(
        [sys.executable, "-m", "hnn_pl", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert out.startswith("usage: python -m hnn_pl <command>")
    assert "fit" in out and "spring.yaml" in out
    # instant: neither Lightning nor torch is imported for it
    code = "import sys; from hnn_pl.commands.main import main; main(['--help']); "
    code += "assert not {'torch', 'lightning'} & set(sys.modules), 'heavy imports'"
    subprocess.run([sys.executable, "-c", code], capture_output=True, check=True)


def test_version_is_defined_once():
    from importlib.metadata import version

    import hnn_pl

    assert version("hnn_pl") == hnn_pl.__version__
    out = subprocess.run(
        [sys.executable, "-m", "hnn_pl", "--version"], capture_output=True, text=True, check=True
    ).stdout
    assert out.split() == ["hnn_pl", hnn_pl.__version__]


def test_short_class_names_fit(tmp_path):
    """``--model HNN --data SimulatedData --data.system MassSpring``: no import paths."""
    from hnn_pl import HNN, SimulatedData
    from hnn_pl.systems import MassSpring

    cli = cli_main(
        ["fit", "--model", "HNN", "--data", "SimulatedData", "--data.system", "MassSpring"]
        + ["--data.n_trajectories=4", "--trainer.max_steps=2", "--trainer.logger=false"]
        + ["--trainer.enable_model_summary=false", f"--trainer.default_root_dir={tmp_path}"]
        + ["--trainer.enable_progress_bar=false", f"--data.cache_dir={tmp_path / 'cache'}"]
        + ["--data.full_batch_steps=2"]
    )
    assert type(cli.model) is HNN and type(cli.datamodule) is SimulatedData
    assert type(cli.datamodule.system) is MassSpring
    assert cli.model.hparams.input_dim == 2 and cli.trainer.global_step == 2


@pytest.mark.parametrize(
    "args, option",
    [
        (["--model.help", "HNN"], "--model.hidden_dim"),
        (["--model.help", "Baseline"], "--model.hidden_dim"),
        (["--model.help", "DissipativeHNN"], "--model.momentum_only"),
        (["--data.help", "SimulatedData"], "--data.n_trajectories"),
        (["--data", "SimulatedData", "--data.system.help", "TwoBody"], "orbit_noise"),
    ],
)
def test_class_help_by_short_name(args, option, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/x/hnn_pl/__main__.py"])
    with pytest.raises(SystemExit) as exit_:
        cli_main(["fit", *args])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m hnn_pl") and option in out, out


@pytest.mark.parametrize(
    "argv0, prog",
    [("/x/hnn_pl/__main__.py", "python -m hnn_pl"), ("/venv/bin/hnn-pl", "hnn-pl")],
)
def test_usage_names_the_program(argv0, prog, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", [argv0])
    with pytest.raises(SystemExit):
        cli_main(["fit", "--help"])
    out = capsys.readouterr().out
    assert out.startswith(f"usage: {prog} [options] fit") and "__main__" not in out, out


@pytest.mark.parametrize("config", ["spring_fast.yaml", "pixel_fast.yaml"])
def test_short_fit_logs_scalars_images_and_checkpoint(config, tmp_path):
    """9 steps, validated every 2 epochs (4 steps each for the full-batch tasks, 2 for
    the pixel task): the last validation and its checkpoint come at step 8, inside the
    fit; ``last.ckpt`` must still hold step 9, the model the end-of-fit metrics are of."""
    cli = _fit(config, tmp_path, steps=9, extra=["--trainer.check_val_every_n_epoch=2"])
    trainer = cli.trainer
    assert trainer.global_step == 9
    log_dir = trainer.logger.log_dir
    assert Path(log_dir).name.startswith("version_")
    best = Path(trainer.checkpoint_callback.best_model_path)
    assert best.is_file() and best.parent == Path(log_dir, "checkpoints")
    for path in (best, Path(log_dir, "checkpoints", "last.ckpt")):
        assert torch.load(path, weights_only=True)["global_step"] == 9
    tags = _tags(log_dir)
    expected = {"train/loss", "val/loss", "rollout/energy_mse", "rollout/state_mse"}
    if "baseline" not in config:
        expected.add("rollout/conserved_drift")
    else:
        assert "rollout/conserved_drift" not in tags["scalars"]
    assert expected <= set(tags["scalars"])
    assert {"rollout/phase_portrait", "rollout/energy"} <= set(tags["images"])


#: a twin config's suffix: its model, then an optional recipe of it (``_fast``)
_TWIN = re.compile(r"_(baseline|dissipative|lnn|mechanical_hnn|mechanical_lnn)(_fast)?$")
#: the model class of a twin config, by its suffix
_TWIN_CLASS = {
    "dissipative": "DissipativeHNN",
    "lnn": "LNN",
    "mechanical_hnn": "MechanicalHNN",
    "mechanical_lnn": "MechanicalLNN",
}


def _run_name(config: str) -> str:
    """The run name a bundled config logs under (a contract: README, dashboards)."""
    stem = Path(config).stem
    return stem if _TWIN.search(stem) else f"{stem}_hnn"


def _model_class(config: str) -> str:
    stem = Path(config).stem
    twin = _TWIN.search(stem)
    if twin and twin.group(1) in _TWIN_CLASS:
        return _TWIN_CLASS[twin.group(1)]
    kind = "Baseline" if stem.endswith("_baseline") else "HNN"
    return f"Autoencoder{kind}" if stem.startswith("pixel") else kind


@functools.cache
def _resolved_text(config: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit_:
        cli_main(["fit", "--config", config, "--print_config"])
    assert not exit_.value.code
    return out.getvalue()


def _resolved(config: str) -> dict:
    """``fit --config NAME --print_config``, in process, as a mapping."""
    import yaml

    return yaml.safe_load(_resolved_text(config))


@pytest.mark.parametrize("config", CONFIGS)
def test_every_config_resolves_with_the_shared_trainer_defaults(config):
    """Each bundled config loads (``--print_config``) under its run name, with its
    model class, its task's callbacks and the trainer settings of every run."""
    cfg = _resolved(config)
    trainer = cfg["trainer"]
    assert trainer["logger"]["init_args"]["name"] == _run_name(config)
    assert trainer["logger"]["init_args"]["save_dir"] == "lightning_logs"
    assert cfg["model"]["class_path"].rsplit(".", 1)[1] == _model_class(config)
    assert cfg["seed_everything"] == 0
    assert (trainer["accelerator"], trainer["devices"], trainer["max_epochs"]) == ("cpu", 1, -1)
    assert trainer["inference_mode"] is False and trainer["enable_model_summary"] is False
    task = re.sub(
        r"(_fast|_traj|_positions(_fd)?|_100)?(_baseline|_dissipative|_lnn|_mechanical_[hl]nn)?"
        r"(_fast)?$",
        "",
        Path(config).stem,
    )
    assert [c["init_args"]["task"] for c in trainer["callbacks"]] == [task, task]


#: twins with a recipe of their own: the settings they may set apart from their HNN config
_OWN_RECIPE = {
    "spring_positions_mechanical_hnn": (("trainer", "max_steps"), ("data", "batch_size")),
    "chain2_mechanical_hnn_fast": (("trainer", "max_steps"), ("model", "hidden_dim")),
    **{f"chain{n}{size}_lnn": (("model", "loss"),) for n in (2, 3) for size in ("", "_100")},
    **{
        f"chain{n}_100_mechanical_hnn": (
            ("trainer", "max_steps"),
            ("trainer", "precision"),
            ("model", "polish_steps"),
            ("data", "dtype"),
        )
        for n in (2, 3)
    },
}


@pytest.mark.parametrize("config", [c for c in CONFIGS if _TWIN.search(Path(c).stem)])
def test_a_twin_config_differs_from_its_hnn_config_in_model_class_and_run_name(config):
    twin = _resolved(config)
    hnn = _resolved(_TWIN.sub("", Path(config).stem) + ".yaml")
    own = set(twin["model"]["init_args"]) - set(hnn["model"]["init_args"])  # the class's own
    for cfg in (twin, hnn):
        for section, key in _OWN_RECIPE.get(Path(config).stem, ()):
            part = cfg[section]
            part = part.get("init_args", part)
            part.pop(key)
        cfg["trainer"]["logger"]["init_args"].pop("name")
        cfg["model"].pop("class_path")
        cfg["model"]["init_args"].pop("momentum_only", None)
        for k in own:
            cfg["model"]["init_args"].pop(k, None)
    assert twin == hnn


@pytest.fixture
def short_rollouts(monkeypatch):
    """The callbacks' protocols over their first 5 held-out starts and a tenth of the
    horizon (a protocol on the held-out trajectories' own times, ``t_end=None``: their
    first 5, whole; the chain pendulum's simulated 3 s: the system's truth over 0.3 s):
    the same code, a small part of its work (the protocols' numbers are tested
    elsewhere; here every config must run)."""
    import hnn_pl.callbacks

    real = hnn_pl.callbacks.task_protocol

    def short(task, name="clean", overrides=None):
        p = real(task, name, overrides)
        if not hasattr(p, "max_starts"):
            return p
        if p.t_end is None and task.startswith("chain"):
            return p.replace(max_starts=5, t_end=0.3, n_points=11)
        if p.t_end is None:
            return p.replace(max_starts=5)
        return p.replace(max_starts=5, t_end=p.t_end / 10, n_points=max(2, p.n_points // 10))

    monkeypatch.setattr(hnn_pl.callbacks, "task_protocol", short)


def _fit_kind(config: str) -> tuple:
    """What a fit exercises beyond options: the model class, the data class, the
    objective and what is observed (the last value of each along the config's ``base:``
    chain)."""
    kind = {"model": None, "data": None, "objective": None, "observe": None}
    for _, lines in config_chain(str(CONFIG_DIR / config)):
        model, data = lines.get("model") or {}, lines.get("data") or {}
        kind["model"] = model.get("class_path", kind["model"])
        kind["data"] = data.get("class_path", kind["data"])
        kind["objective"] = (model.get("init_args") or {}).get("objective", kind["objective"])
        kind["observe"] = (data.get("init_args") or {}).get("observe", kind["observe"])
    return tuple(kind.values())


def _base_of(config: str) -> str | None:
    """The config's ``base:`` as a file name (``None``: it has none)."""
    base = load_config_file(str(CONFIG_DIR / config)).get("base")
    return None if base is None else base if base.endswith(".yaml") else f"{base}.yaml"


def _kind_pairs(kind: tuple) -> set[tuple]:
    """Every pair of a fit's kind's parts (:func:`_fit_kind`), each with its positions."""
    return {(i, j, kind[i], kind[j]) for i, j in itertools.combinations(range(len(kind)), 2)}


@functools.cache
def _default_tier_fits() -> frozenset[str]:
    """The configs :func:`test_every_state_config_fits_three_steps` fits in the default
    tier: every config without a base (each task's data), and a config with one unless
    earlier configs already fit every pair of its kind's parts (model class, data class,
    objective, observation: :func:`_fit_kind`), as most of a task's recipe variants
    (``_fast``, ``_traj``, the 100-chunk chain, a model swapped in) do: their code is the
    same, their options are parsed and type-checked by ``test_every_config_resolves_…``.
    Of the 3-link chain's configs only ``chain3_100.yaml`` (the 2-link code on other
    data). The slow tier fits every config."""
    fits, pairs = set(), set()
    for config in sorted(c for c in CONFIGS if not c.startswith("pixel")):
        kind = _fit_kind(config)
        if config.startswith("chain3"):
            new = config == "chain3_100.yaml"
        else:
            new = _base_of(config) is None or not _kind_pairs(kind) <= pairs
        if new:
            fits.add(config)
            pairs |= _kind_pairs(kind)
    return frozenset(fits)


def test_the_default_tier_fits_every_model_and_data_class():
    """The tiering of the three-step fits leaves every model class and every data class
    of the state configs, every pair of two parts of their kinds (model and data, model
    and objective, data and observation, …) and every config without a base, fitted in
    the default tier."""
    state = [c for c in CONFIGS if not c.startswith("pixel")]
    fast = _default_tier_fits()
    assert set().union(*map(_kind_pairs, map(_fit_kind, fast))) == set().union(
        *map(_kind_pairs, map(_fit_kind, state))
    )
    assert {_fit_kind(c)[:2] for c in fast} == {_fit_kind(c)[:2] for c in state}
    assert {c for c in state if _base_of(c) is None and not c.startswith("chain3")} <= fast


def _fit_case(config: str):
    fast = config in _default_tier_fits()
    return config if fast else pytest.param(config, marks=pytest.mark.slow)


@pytest.mark.parametrize("config", [_fit_case(c) for c in CONFIGS if not c.startswith("pixel")])
def test_every_state_config_fits_three_steps(config, tmp_path, data_cache, short_rollouts):
    """Three steps of each state config: it trains, validates and rolls out under its
    run name and model class (a short rollout: ``short_rollouts``). The configs of a
    task share their data: one cache."""
    cache = data_cache
    extra = ["--model.init_args.inner_steps=1", f"--data.init_args.cache_dir={cache}"]
    extra += ["--trainer.limit_val_batches=2"]
    if config.startswith("chain"):  # the benchmark's 3 s of 300 trajectories cost seconds
        extra += [f"--data.init_args.{split}=8" for split in ("n_train", "n_val", "n_test")]
        extra += ["--data.init_args.horizon=0.3"]
    cli = _fit(config, tmp_path, steps=3, extra=extra)
    assert cli.trainer.global_step == 3
    assert type(cli.model).__name__ == _model_class(config)
    log_dir = Path(cli.trainer.logger.log_dir)
    assert log_dir.parent == tmp_path / _run_name(config)
    assert {"train/loss", "val/loss", "rollout/energy_mse"} <= set(_tags(str(log_dir))["scalars"])


def test_a_config_extends_its_base(tmp_path, monkeypatch):
    """``base:`` reads the base first, then the config's own lines over it; bases chain,
    and resolve beside the config or among the bundled configs."""
    from hnn_pl.commands.config_paths import config_chain, resolve_config_args

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.yaml").write_text("base: spring_fast\ntrainer: {max_steps: 7}\n")
    (tmp_path / "twin.yaml").write_text("base: mine.yaml\nmodel: {class_path: Baseline}\n")
    chain = [Path(path).name for path, _ in config_chain("twin.yaml")]
    assert chain == ["spring.yaml", "spring_fast.yaml", "mine.yaml", "twin.yaml"]
    args = resolve_config_args(["fit", "-c", "twin.yaml", "--trainer.max_steps=3"])
    assert args[:3] == ["fit", "--config", str(CONFIG_DIR / "spring.yaml")]
    assert args.count("--config") == 4 and args[-1] == "--trainer.max_steps=3"
    cli = cli_main(
        ["--config", "twin.yaml", "--trainer.logger=false"]
        + [f"--data.init_args.cache_dir={tmp_path}"],
        run=False,
        save_config=False,
    )
    assert type(cli.model).__name__ == "Baseline" and cli.trainer.max_steps == 7
    assert cli.model.hparams.schedule == "onecycle" and cli.model.hparams.lr == 1e-2
    assert cli.model.hparams.weight_decay == 0.0 and cli.model.hparams.inner_steps == 10
    # a class that lacks some of the base's init_args keeps those it has
    other = tmp_path / "other.yaml"
    other.write_text("base: spring_traj\nmodel: {class_path: hnn_pl.models.AutoencoderBaseline}\n")
    init_args = _resolved(str(other))["model"]["init_args"]
    assert "objective" not in init_args and init_args["lr"] == 3e-3


@pytest.mark.parametrize(
    "config", ["spring.yaml", pytest.param("spring_baseline.yaml", marks=pytest.mark.slow)]
)
def test_test_command_reports_losses_and_rollout_metrics(config, tmp_path, short_rollouts):
    """``test`` of a fitted checkpoint under both inference modes (the HNN's field takes
    its gradient without autograd); the baseline's ``test`` is in the default tier in
    ``test_runs``."""
    ckpt = _fit(config, tmp_path).trainer.checkpoint_callback.best_model_path
    # the default Trainer(inference_mode=True) must work too: the HNN field needs no autograd
    for inference_mode in ("false", "true"):
        cli = cli_main(
            [
                "test",
                "--config",
                config,
                "--ckpt_path",
                ckpt,
                f"--trainer.inference_mode={inference_mode}",
            ]
            + _common(tmp_path)
        )
        metrics = cli.trainer.callback_metrics
        assert {"test/loss", "rollout/energy_mse", "rollout/state_mse"} <= set(metrics)
        assert all(torch.isfinite(v) for v in metrics.values())


def test_predict_and_validate_commands(tmp_path, short_rollouts):
    ckpt = _fit("pendulum.yaml", tmp_path).trainer.checkpoint_callback.best_model_path
    cli = cli_main(
        ["validate", "--config", "pendulum.yaml", "--ckpt_path", ckpt] + _common(tmp_path)
    )
    assert "val/loss" in cli.trainer.callback_metrics
    cli = cli_main(
        ["predict", "--config", "pendulum.yaml", "--ckpt_path", ckpt] + _common(tmp_path)
    )
    assert cli.trainer.predict_loop.predictions[0].shape == (1125, 2)


def test_checkpoint_round_trip_rolls_out_the_same(tmp_path):
    from hnn_pl import HNN

    cli = _fit("spring.yaml", tmp_path, steps=10)
    model = cli.model
    loaded = HNN.load_from_checkpoint(cli.trainer.checkpoint_callback.best_model_path)
    assert all(loaded.hparams[k] == model.hparams[k] for k in loaded.hparams)
    y0 = cli.datamodule.test_y[0]
    t = torch.linspace(0, 5, 50)
    torch.testing.assert_close(
        loaded.rollout(y0, t, method="rk4"), model.rollout(y0, t, method="rk4")
    )


@pytest.mark.parametrize("command", ["reproduce", "bump", "stress"])
def test_subcommand_help_names_the_program(command, capsys, monkeypatch):
    from hnn_pl.commands.main import main

    monkeypatch.setattr(sys, "argv", ["/venv/bin/hnn-pl", command, "--help"])
    with pytest.raises(SystemExit):
        main()
    assert capsys.readouterr().out.startswith(f"usage: hnn-pl {command}")


def test_top_level_help_says_what_predict_writes(capsys, monkeypatch):
    from hnn_pl.commands.main import main

    monkeypatch.setattr(sys, "argv", ["/venv/bin/hnn-pl"])
    main(["--help"])
    predict = capsys.readouterr().out.split("\n  predict ")[1].split("\n  reproduce")[0]
    assert "rollouts.pt" in predict and "dy/dt" not in predict


def _lines(text: str) -> list[str]:
    """Terminal output as its lines: a progress bar's redraws (``\\r``) split too."""
    return [line.rstrip() for line in re.split(r"[\r\n]", text) if line.strip()]


def _summary(text: str) -> dict[str, str]:
    """The ``name  value`` rows of a command's closing summary (its last lines)."""
    lines = _lines(text)
    start = max(i for i, line in enumerate(lines) if line.startswith("run "))
    return dict(line.strip().split(None, 1) for line in lines[start:] if not line.endswith(":"))


def test_fit_test_and_predict_end_with_their_run_checkpoint_and_metrics(
    tmp_path, capsys, short_rollouts
):
    """The last lines say where a command went and how: the run, the checkpoint and the
    rollout's metrics as a table. The bar counts optimiser steps (2 batches × 2 inner
    steps: 4/4), the final rollout is a step of its own, and predict's line stands
    alone, not glued to a bar."""
    cli = _fit("spring_fast.yaml", tmp_path, extra=["--trainer.enable_progress_bar=true"])
    out = capsys.readouterr().out
    run, ckpt = Path(cli.trainer.log_dir), Path(cli.trainer.log_dir, "checkpoints", "last.ckpt")
    rows = _summary(out)
    assert rows["run"] == str(run) and rows["checkpoint"] == str(ckpt) and ckpt.is_file()
    (rollout,) = [c for c in cli.trainer.callbacks if type(c).__name__ == "RolloutCallback"]
    shown = {k for k in rollout.metrics if not k.startswith("floor_")}  # floors: in the logs
    assert rows["metric"] == "value" and set(rows) == {"run", "checkpoint", "metric", *shown}
    assert float(rows["energy_mse"]) == pytest.approx(rollout.metrics["energy_mse"], rel=1e-3)
    assert _lines(out)[-len(shown) - 2] == "final rollout:"
    assert re.search(r"Epoch \d+: 100%\|[^|]*\| 4/4 \[[^]]*step/s", out)
    assert not re.search(r"Epoch \d+: [^|]*\|[^|]*\| 2/2 \[", out)  # not the batches
    assert re.search(r"Final rollout: [^|]*\| 1/1 \[", out)

    cli = cli_main(
        ["test", "--config", "spring_fast.yaml", "--ckpt_path", str(run)] + _common(tmp_path)
    )
    rows = _summary(capsys.readouterr().out)
    assert rows["run"] == str(run) and rows["checkpoint"] == str(ckpt)
    logged = cli.trainer.callback_metrics
    assert float(rows["state_mse"]) == pytest.approx(float(logged["rollout/state_mse"]), rel=1e-3)
    assert float(rows["test/loss"]) == pytest.approx(float(logged["test/loss"]), rel=1e-3)

    argv = ["predict", "--config", "spring_fast.yaml", "--ckpt_path", str(run)]
    cli_main(argv + _common(tmp_path) + ["--trainer.enable_progress_bar=true"])
    out = capsys.readouterr().out
    rows = _summary(out)
    assert rows["rollouts"] == str(run / "rollouts.pt") and rows["checkpoint"] == str(ckpt)
    saved = torch.load(run / "rollouts.pt", weights_only=True)["metrics"]
    assert float(rows["energy_mse"]) == pytest.approx(saved["energy_mse"], rel=1e-3)
    wrote = [line for line in _lines(out) if "wrote rollouts" in line]
    assert len(wrote) == 1 and wrote[0].startswith("wrote rollouts (")


@pytest.mark.parametrize("command", ["reproduce", "bump"])
def test_plain_commands_help_imports_neither_torch_nor_lightning(command):
    """``reproduce --help`` and ``bump --help`` are as quick as ``--help``."""
    code = "import sys\nfrom hnn_pl.commands.main import main\ntry:\n"
    code += f"    main([{command!r}, '--help'])\nexcept SystemExit:\n    pass\n"
    code += "assert not {'torch', 'lightning'} & set(sys.modules), 'heavy imports'"
    subprocess.run([sys.executable, "-c", code], capture_output=True, check=True)
