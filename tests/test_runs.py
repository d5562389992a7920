"""One home per concept: the task registry, the rollout engine, runs told apart, predict."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
import yaml

import hnn_pl
from hnn_pl import evaluation, tasks
from hnn_pl.callbacks import FinalCheckpoint, RolloutCallback
from hnn_pl.commands.cli import cli_main
from hnn_pl.commands.config_paths import bundled_configs, config_chain, resolve_config
from hnn_pl.data import SimulatedData
from hnn_pl.evaluation import Protocol, ReferenceProtocol
from hnn_pl.experiments import paper
from hnn_pl.models import HNN, Baseline
from hnn_pl.systems import MassSpring

PACKAGE = Path(hnn_pl.__file__).parent


def test_every_task_names_its_configs_and_published_numbers_once():
    configs = set(bundled_configs())
    # the paper's table: every task, in order, then the tasks beyond it (the chain pendulums)
    assert list(paper.PAPER) == list(tasks.TASKS)[: len(paper.PAPER)]
    for row in paper.PAPER.values():
        for recipe in paper.RECIPES:
            for model in row.models_for(recipe):
                assert row.config(model, recipe) in configs
        for model in ("baseline", "hnn"):
            assert row.published[model].energy_mse > 0
    for task in tasks.TASKS.values():
        assert isinstance(evaluation.task_protocol(task.name, "clean"), Protocol)
        want = ReferenceProtocol if task.name in paper.PAPER and task.kind == "state" else Protocol
        assert isinstance(evaluation.task_protocol(task.name, "reference"), want)
    assert paper.get("spring").config("baseline", "fast") == "spring_fast_baseline.yaml"
    real = paper.get("real_pendulum").config("dissipative", "fast")
    assert real == "real_pendulum_fast_dissipative.yaml"
    assert paper.get("spring").config("hnn", "traj") == "spring_traj.yaml"
    with pytest.raises(ValueError, match="model in"):
        paper.get("spring").config("dissipative")
    with pytest.raises(ValueError, match="model in"):
        paper.get("three_body").config("hnn", "traj")
    for registry in (tasks, paper):
        with pytest.raises(KeyError, match="known tasks"):
            registry.get("spring_mass")


def test_no_task_name_branches_outside_the_registry():
    """Task-specific behaviour lives in tasks.py: no ``== "pixel"`` tests elsewhere."""
    offenders = [
        f"{p.relative_to(PACKAGE)}:{i}"
        for p in PACKAGE.rglob("*.py")
        if p.name != "tasks.py"
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if re.search(r"""(==|!=|\bin)\s*\(?["'](pixel|spring|pendulum|two_body)["']""", line)
    ]
    assert offenders == []


def test_configs_name_a_protocol_and_do_not_restate_it():
    for name in bundled_configs():
        chain = [cfg for _, cfg in config_chain(resolve_config(name))]
        callbacks = [cfg["trainer"]["callbacks"] for cfg in chain if "callbacks" in cfg["trainer"]]
        rollout = [c for c in callbacks[-1] if "RolloutCallback" in c["class_path"]]
        assert len(rollout) == 1, name
        assert set(rollout[0]["init_args"]) <= {"task", "protocol", "every_n_epochs"}, name
        assert rollout[0]["init_args"]["task"] in tasks.TASKS


def test_protocol_overrides_are_checked_when_the_callback_is_built():
    cb = RolloutCallback("spring", overrides={"method": "rk4", "step_size": 0.05})
    assert cb.protocol.method == "rk4" and cb.protocol.t_end == 20.0
    with pytest.raises(ValueError, match="unknown method"):
        RolloutCallback("spring", overrides={"method": "rk5"})
    with pytest.raises(ValueError, match="n_points"):
        RolloutCallback("spring", overrides={"n_points": 0})
    with pytest.raises(ValueError, match="overrides"):
        RolloutCallback("spring", overrides={"horizon": 3})
    with pytest.raises(ValueError, match="no protocol 'exact'"):
        RolloutCallback("spring", protocol="exact")
    assert isinstance(RolloutCallback("spring", "reference").protocol, ReferenceProtocol)


class _Exact(torch.nn.Module):
    def __init__(self, system) -> None:
        super().__init__()
        self.system = system

    def vector_field(self, t, y):
        return self.system.vector_field(t, y)


def test_engine_scores_the_true_field_near_zero_and_a_model_above(tmp_path):
    dm = SimulatedData(MassSpring(), cache_dir=str(tmp_path), dtype="float64")
    dm.setup()
    p = evaluation.task_protocol("spring", "clean").replace(n_points=50)
    exact, r = evaluation.evaluate(_Exact(dm.system), dm, p)
    assert exact["energy_mse"] < 1e-14 and r.y_pred.shape == (50, 25, 2)
    model = HNN(input_dim=2, hidden_dim=16)
    learned, r = evaluation.evaluate(model, dm, p)
    assert learned["energy_mse"] > 1e3 * exact["energy_mse"]
    assert r.h_pred.shape == (50, 25) and learned["conserved_drift"] < 1e-6
    assert model.training


def test_python_rollout_api_returns_states_energies_and_times():
    model = Baseline(input_dim=2, hidden_dim=16).double()
    y0 = torch.tensor([[1.0, 0.0], [0.0, 0.5]], dtype=torch.float64)
    t = torch.linspace(0, 1, 11, dtype=torch.float64)
    out = hnn_pl.rollout(model, y0, t, method="rk4", energy=MassSpring().energy)
    assert out.y_pred.shape == (11, 2, 2) and out.e_pred.shape == (11, 2) and out.h_pred is None
    direct = hnn_pl.odeint(model.field.vector_field, y0, t, method="rk4")
    torch.testing.assert_close(out.y_pred, direct, rtol=0, atol=0)
    hnn = HNN(input_dim=2, hidden_dim=16)
    out = hnn_pl.rollout(hnn, y0.float(), t, method="rk4")
    assert out.y_pred.dtype == torch.float64 and out.h_pred.shape == (11, 2)


def _common(tmp_path: Path) -> list[str]:
    return [
        f"--trainer.logger.init_args.save_dir={tmp_path / 'logs'}",
        f"--data.init_args.cache_dir={tmp_path / 'cache'}",
        "--trainer.enable_progress_bar=false",
        "--data.init_args.full_batch_steps=2",
    ]


@pytest.fixture(scope="module", params=["spring.yaml", "spring_baseline.yaml"])
def run(request, tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp(request.param.split(".")[0])
    cli = cli_main(["fit", "--config", request.param, "--trainer.max_steps=4", *_common(tmp_path)])
    return request.param, tmp_path, cli


def test_each_config_logs_under_its_own_name_with_what_tells_runs_apart(run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import plugin_data_pb2

    config, tmp_path, cli = run
    name = "spring_baseline" if "baseline" in config else "spring_hnn"
    log_dir = Path(cli.trainer.logger.log_dir)
    assert log_dir == tmp_path / "logs" / name / "version_0"
    hp = yaml.safe_load((log_dir / "hparams.yaml").read_text())
    cls = Baseline if "baseline" in config else HNN
    assert hp["model_class"] == f"{cls.__module__}.{cls.__qualname__}"
    assert hp["system"]["class_path"] == "hnn_pl.systems.mass_spring.MassSpring"
    assert hp["system"]["init_args"]["alpha"] == 1.0
    assert (log_dir / "checkpoints" / "last.ckpt").is_file()
    acc = EventAccumulator(str(log_dir))
    acc.Reload()
    assert "hp_metric" not in acc.Tags()["scalars"]
    content = acc.PluginTagToContent("hparams")
    experiment = plugin_data_pb2.HParamsPluginData.FromString(content["_hparams_/experiment"])
    assert [m.name.tag for m in experiment.experiment.metric_infos] == ["rollout/energy_mse"]
    assert "rollout/energy_mse" in acc.Tags()["scalars"]
    # the HParams tab: one session, holding the recipe, the data and what tells runs apart
    assert _hparams_summaries(log_dir) == 1
    start = plugin_data_pb2.HParamsPluginData.FromString(content["_hparams_/session_start_info"])
    shown = start.session_start_info.hparams
    assert shown["lr"].number_value == 1e-3 and shown["hidden_dim"].number_value == 200
    assert shown["schedule"].string_value == "constant"
    assert shown["noise_std"].number_value == 0.1 and shown["n_trajectories"].number_value == 50
    assert shown["model_class"].string_value == hp["model_class"]
    assert {"system/class_path", "rollout_protocol/method", "inner_steps"} <= set(shown)
    assert "_instantiator" not in shown and "_instantiator" not in hp  # LightningCLI's, no option
    assert shown["objective"].string_value == hp["objective"] == "derivative"  # "auto", resolved


def _hparams_summaries(log_dir: Path) -> int:
    """How many hparams sessions the run's event files hold (TensorBoard shows the first)."""
    from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

    return sum(
        value.tag == "_hparams_/session_start_info"
        for path in log_dir.glob("events.out.tfevents.*")
        for event in EventFileLoader(str(path)).Load()
        for value in event.summary.value
    )


def test_test_and_predict_log_into_the_run_they_evaluate(run):
    """``--ckpt_path`` may name the run or the run name's directory (its latest run);
    ``test`` and ``predict`` add to that run instead of starting a ``version_1``."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config, tmp_path, cli = run
    log_dir = Path(cli.trainer.logger.log_dir)
    fit_config = (log_dir / "config.yaml").read_text()
    test = cli_main(
        ["test", "--config", config, f"--ckpt_path={log_dir.parent}", *_common(tmp_path)]
    )
    assert Path(test.trainer.logger.log_dir) == log_dir
    predict = cli_main(
        ["predict", "--config", config, f"--ckpt_path={log_dir}", *_common(tmp_path)]
    )
    assert Path(predict.trainer.logger.log_dir) == log_dir
    assert sorted(p.name for p in log_dir.parent.iterdir()) == ["version_0"]
    assert (log_dir / "config.yaml").read_text() == fit_config
    assert (log_dir / "config_test.yaml").is_file() and (log_dir / "rollouts.pt").is_file()
    acc = EventAccumulator(str(log_dir))
    acc.Reload()
    assert {"test/loss", "rollout/energy_mse"} <= set(acc.Tags()["scalars"])
    assert _hparams_summaries(log_dir) == 1


def test_a_missing_checkpoint_fails_before_any_run_directory_exists(tmp_path):
    logs = tmp_path / "logs"
    for path in (logs / "spring_hnn", logs / "spring_hnn" / "version_0" / "last.ckpt"):
        with pytest.raises(FileNotFoundError, match="checkpoint"):
            cli_main(["test", "--config", "spring.yaml", f"--ckpt_path={path}", *_common(tmp_path)])
    assert not logs.exists()


@pytest.mark.parametrize(
    "option", ["--optimizer=SGD", "--optimizer.lr=0.1", "--lr_scheduler", "--optimizer"]
)
def test_lightning_optimizer_options_are_refused_not_ignored(option, tmp_path):
    with pytest.raises(ValueError, match="model's recipe.*--model.init_args.optimizer"):
        cli_main(["fit", "--config", "spring.yaml", option, "SGD", *_common(tmp_path)])


def test_class_name_runs_get_the_configs_defaults(tmp_path, monkeypatch):
    """No config: the paper's 2000 steps, a TensorBoard run named after the classes."""
    monkeypatch.chdir(tmp_path)
    args = ["--model", "HNN", "--data", "SimulatedData", "--data.system", "MassSpring"]
    cli = cli_main([*args, f"--data.cache_dir={tmp_path / 'cache'}"], run=False)
    assert cli.trainer.max_steps == 2000 and cli.trainer.max_epochs == -1
    assert Path(cli.trainer.logger.log_dir) == Path("lightning_logs/mass_spring_hnn/version_0")
    assert isinstance(cli.trainer.checkpoint_callback, FinalCheckpoint)


def test_predict_writes_rollouts_beside_the_run_and_says_where(run, capsys):
    config, tmp_path, cli = run
    ckpt = Path(cli.trainer.checkpoint_callback.last_model_path)
    cli_main(["predict", "--config", config, f"--ckpt_path={ckpt}", *_common(tmp_path)])
    path = ckpt.parent.parent / "rollouts.pt"
    assert str(path) in capsys.readouterr().out
    out = torch.load(path, weights_only=True)
    assert out["y_pred"].shape == out["y_true"].shape == (200, 25, 2)
    assert out["energy_pred"].shape == (200, 25) and "dydt" not in out
    assert ("h_pred" in out) == ("baseline" not in config)
    torch.testing.assert_close(out["y_pred"][0], out["y_true"][0])
    starts = tmp_path / "starts.pt"
    torch.save(torch.tensor([[0.5, 0.0], [0.0, 0.7], [1.0, 1.0]]), starts)
    args = ["--trainer.callbacks.init_args.starts=" + str(starts)]
    # the writer is the second callback: address it by position-independent override
    cli_main(
        ["predict", "--config", config, f"--ckpt_path={ckpt}", *_common(tmp_path)]
        + ["--trainer.callbacks+=hnn_pl.callbacks.RolloutWriter"]
        + ["--trainer.callbacks.init_args.filename=given.pt", *args]
    )
    given = torch.load(ckpt.parent.parent / "given.pt", weights_only=True)
    assert given["y"].shape == (200, 3, 2) and given["energy"].shape == (200, 3)


def test_predict_with_the_implicit_midpoint_rule(run):
    """``predict`` integrates with a symplectic method on request: the same paths as
    dopri5 to the rule's O(h²) error, ``H_θ`` kept along them."""
    config, tmp_path, cli = run
    ckpt = Path(cli.trainer.checkpoint_callback.last_model_path)
    midpoint = '{"method": "implicit_midpoint", "step_size": 0.02}'
    cli_main(
        ["predict", "--config", config, f"--ckpt_path={ckpt}", *_common(tmp_path)]
        + ["--trainer.callbacks+=hnn_pl.callbacks.RolloutWriter"]
        + ["--trainer.callbacks.init_args.filename=midpoint.pt"]
        + [f"--trainer.callbacks.init_args.overrides={midpoint}"]
    )
    mid = torch.load(ckpt.parent.parent / "midpoint.pt", weights_only=True)
    assert mid["metrics"]["diverged_rows"] == 0
    model = type(cli.model).load_from_checkpoint(ckpt)
    ref = hnn_pl.rollout(model, mid["y_true"][0], mid["t"], method="dopri5", rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(mid["y_pred"], ref.y_pred, rtol=0, atol=1e-3)
    if "h_pred" in mid:
        h = mid["h_pred"]
        assert (h - h[:1]).abs().max() / h.std() < 1e-3
