"""Resumed and repeated fits (issue 31, items 3, 4, 6): learned states belong to the data
they were learned on, options act or are refused, checkpoints load as ``fit`` saved them."""

from __future__ import annotations

import copy
import math
from types import SimpleNamespace

import lightning as L
import pytest
import torch
from lightning.pytorch import Callback

from hnn_pl.commands.cli import QUIET_TRAINER
from hnn_pl.commands.cli_errors import given_model_options
from hnn_pl.data import SimulatedData
from hnn_pl.models import HNN, AutoencoderHNN
from hnn_pl.models.base import (
    TRAJECTORY_OPTIONS,
    data_source,
    forget_last_parameter,
    observed_data,
)
from hnn_pl.safe_io import (
    check_finite_weights,
    check_same_system,
    checkpoint_init_args,
    load_checkpoint,
    refuse_changed_options,
)
from hnn_pl.systems import MassSpring, Pendulum


def _dm(tmp_path, seed=0, n=6, window=3, **kwargs) -> SimulatedData:
    """A small spring draw: ``n`` trajectories of 8 samples, half of them for training."""
    return SimulatedData(
        MassSpring(),
        n_trajectories=n,
        n_points=8,
        seed=seed,
        window=window,
        full_batch_steps=1,
        cache_dir=str(tmp_path / "cache"),
        **kwargs,
    )


def _model(**kwargs) -> HNN:
    torch.manual_seed(0)
    return HNN(hidden_dim=8, objective="trajectory", learned_states="sample", **kwargs)


class _AtStart(Callback):
    """The learned states, a field weight and the optimiser state when training starts."""

    def on_train_start(self, trainer, pl_module):
        states = pl_module.states
        self.states = None if states is None else states.detach().clone()
        self.weight = pl_module.field.net.out.weight.detach().clone()
        self.step = trainer.global_step
        self.optimizer = copy.deepcopy(trainer.optimizers[0].state_dict())


def _fit(model, dm, steps=2, ckpt_path=None) -> _AtStart:
    start = _AtStart()
    trainer = L.Trainer(
        max_steps=steps, inference_mode=False, **{**QUIET_TRAINER, "callbacks": [start]}
    )
    trainer.fit(model, dm, ckpt_path=ckpt_path)
    model.last_trainer = trainer
    return start


def _one_line(err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


def _setup(dm: SimulatedData) -> SimulatedData:
    dm.setup("fit")
    return dm


# ------------------------------------------------------------------ fingerprints


def test_fingerprints_match_for_the_same_draw_and_differ_for_another(tmp_path):
    def data(dm, learned="sample"):
        dm = _setup(dm)
        obs = (dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train)
        return observed_data(*obs, data_source(dm), learned)

    a, again = data(_dm(tmp_path)), data(_dm(tmp_path))
    assert a == again and a["rows"] == 3 * 8 and len(a["sha256"]) == 64
    assert a["source"] == "SimulatedData(MassSpring, 6 trajectories, seed 0)"
    others = [
        data(_dm(tmp_path, seed=1)),
        data(_dm(tmp_path, n=8)),
        data(_dm(tmp_path, keep_fraction=0.5)),
        data(_dm(tmp_path, observe="positions")),
        data(_dm(tmp_path, dtype="float64")),
    ]
    assert len({a["sha256"], *(o["sha256"] for o in others)}) == 6
    assert others[1]["rows"] == 4 * 8 and others[2]["rows"] == 3 * 4
    assert others[2]["source"].endswith("(keep_fraction 0.5)")
    assert others[3]["source"].endswith("(observe positions)")
    assert data(_dm(tmp_path), "trajectory")["rows"] == 3


# ------------------------------------------------------------------ refits from Python


def test_a_refit_on_other_data_is_refused_in_one_line(tmp_path):
    model = _model()
    _fit(model, _dm(tmp_path))
    learned = model.states.detach().clone()
    for other, rows in ((_dm(tmp_path, seed=1), 24), (_dm(tmp_path, n=8), 32)):
        with pytest.raises(ValueError) as err:
            _fit(model, other)
        line = _one_line(err)
        assert line.startswith(
            "this model: its learned states were learned on SimulatedData(MassSpring, "
            "6 trajectories, seed 0) (data "
        )
        assert f"{data_source(other)} (data " in line and f", {rows} states)" in line
        assert line.endswith(
            "or set model.init_args.reinit_states: true to start them from these observations"
        )
        assert torch.equal(model.states, learned)


def test_a_refit_on_the_same_data_goes_on_from_the_learned_states(tmp_path):
    model = _model()
    _fit(model, _dm(tmp_path))
    learned = model.states.detach().clone()
    assert not torch.equal(learned, _setup(_dm(tmp_path)).obs_y_train)  # they moved
    start = _fit(model, _dm(tmp_path))  # another object, the same draw
    assert torch.equal(start.states, learned)


def test_a_refit_with_reinit_states_starts_them_from_the_new_observations(tmp_path):
    model = _model(reinit_states=True)
    _fit(model, _dm(tmp_path))
    weight = model.field.net.out.weight.detach().clone()
    other = _dm(tmp_path, n=8)
    start = _fit(model, other)
    assert torch.equal(start.states, _setup(other).obs_y_train) and start.states.shape == (32, 2)
    assert torch.equal(start.weight, weight)  # the field goes on
    assert model.states_data["rows"] == 32 and "8 trajectories" in model.states_data["source"]


def test_init_states_from_positions_compares_the_served_positions(tmp_path):
    model = _model()
    dm = _setup(_dm(tmp_path, observe="positions"))
    model.init_states(dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train, "positions")
    assert model.states.shape == (24, 2) and torch.equal(model.states[:, :1], dm.obs_y_train)
    states = _setup(_dm(tmp_path))
    with pytest.raises(
        ValueError,
        match=r"learned on positions \(data .*, but this fit's data is "
        r"states \(data",
    ):
        model.init_states(states.obs_y_train, states.obs_t_train, states.obs_traj_train, "states")


# ------------------------------------------------------------------ resumed fits


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A 2-step fit of :func:`_model` on :func:`_dm` and its checkpoint."""
    tmp_path = tmp_path_factory.mktemp("trained")
    model = _model()
    _fit(model, _dm(tmp_path))
    path = tmp_path / "model.ckpt"
    model.last_trainer.save_checkpoint(path)
    return tmp_path, path, model


def test_a_resume_on_other_data_is_refused_in_one_line(trained):
    tmp_path, path, _ = trained
    for other, rows in ((_dm(tmp_path, seed=1), 24), (_dm(tmp_path, n=8), 32)):
        with pytest.raises(ValueError) as err:
            _fit(_model(), other, steps=4, ckpt_path=path)
        line = _one_line(err)
        assert line.startswith(
            f"checkpoint {path}: its learned states were learned on "
            "SimulatedData(MassSpring, 6 trajectories, seed 0) (data "
        )
        assert f"but this fit's data is {data_source(other)} (data " in line
        assert f"{rows} states)" in line and "size mismatch" not in line


def test_a_resume_on_the_same_data_takes_the_saved_states(trained):
    tmp_path, path, model = trained
    start = _fit(_model(), _dm(tmp_path), steps=3, ckpt_path=path)
    assert start.step == 2 and torch.equal(start.states, model.states.detach())


def test_a_resume_with_reinit_states_keeps_the_field_and_starts_the_states_anew(trained):
    tmp_path, path, model = trained
    other = _dm(tmp_path, n=8)
    resumed = _model(reinit_states=True)
    start = _fit(resumed, other, steps=4, ckpt_path=path)
    assert start.step == 2 and resumed.last_trainer.global_step == 4
    assert torch.equal(start.states, _setup(other).obs_y_train)
    assert torch.equal(start.weight, model.field.net.out.weight.detach())
    state = start.optimizer["state"]
    states_index = start.optimizer["param_groups"][-1]["params"][-1]
    assert states_index not in state and len(state) == states_index  # field moments kept
    saved = torch.load(path, weights_only=True)["optimizer_states"][0]["state"]
    torch.testing.assert_close(state[0]["exp_avg"], saved[0]["exp_avg"])


def test_forget_last_parameter_drops_only_the_states_moments():
    adam = {
        "state": {0: "w", 1: "b", 2: "states"},
        "param_groups": [{"params": [0, 1]}, {"params": [2]}],
    }
    lbfgs = {"state": {0: "history"}, "param_groups": [{"params": [0, 1, 2]}]}
    ckpt = {"optimizer_states": [adam, lbfgs]}
    forget_last_parameter(ckpt)
    assert adam["state"] == {0: "w", 1: "b"} and lbfgs["state"] == {}


def test_a_checkpoint_without_states_does_not_resume_a_model_that_learns_them(tmp_path):
    plain = HNN(hidden_dim=8, objective="trajectory")
    _fit(plain, _dm(tmp_path))
    path = tmp_path / "plain.ckpt"
    plain.last_trainer.save_checkpoint(path)
    with pytest.raises(
        ValueError, match="holds no learned states but this model has learned_states='sample'"
    ):
        _fit(_model(), _dm(tmp_path), steps=3, ckpt_path=path)


# ------------------------------------------------------------------ loading for evaluation


def test_load_trained_takes_the_learned_states_as_saved(trained):
    _, path, model = trained
    ckpt = load_checkpoint(path)
    for fresh in (_model(), HNN(hidden_dim=8)):  # bump builds the config's model
        fresh.load_trained(ckpt, where="checkpoint C")
        assert torch.equal(fresh.states, model.states.detach())
        torch.testing.assert_close(fresh.field.net.out.weight, model.field.net.out.weight)
    with pytest.raises(ValueError) as err:
        HNN(hidden_dim=16).load_trained(ckpt, where="checkpoint C")
    assert _one_line(err) == (
        "checkpoint C does not fit the config's model (field.net.hidden.0.weight has shape "
        "(8, 2), the config's model (16, 2)): use the config it was trained with"
    )


def test_a_checkpoint_with_weights_that_are_not_finite_is_refused(trained, tmp_path):
    _, path, _ = trained
    ckpt = torch.load(path, weights_only=True)
    ckpt["state_dict"]["field.net.out.weight"][0, :3] = torch.tensor([math.nan, math.inf, 1.0])
    with pytest.raises(ValueError) as err:
        check_finite_weights(ckpt, "checkpoint C")
    assert _one_line(err).startswith(
        "checkpoint C: its weights are not finite (field.net.out.weight: 2 of 8 values are nan "
        "or inf)"
    )
    bad = tmp_path / "nan.ckpt"
    torch.save(ckpt, bad)
    with pytest.raises(ValueError, match=f"checkpoint {bad}: its weights are not finite"):
        load_checkpoint(bad)
    with pytest.raises(ValueError, match="its weights are not finite"):
        _model().load_trained(ckpt)


def test_a_checkpoint_of_another_system_is_refused_naming_both(trained, tmp_path):
    _, path, _ = trained
    ckpt = load_checkpoint(path)
    pendulum = SimulatedData(Pendulum(), cache_dir=str(tmp_path))
    with pytest.raises(ValueError) as err:
        check_same_system(ckpt, pendulum, "checkpoint C")
    assert _one_line(err) == (
        "checkpoint C was trained on hnn_pl.systems.mass_spring.MassSpring but the config's "
        "data is hnn_pl.systems.pendulum.Pendulum: use the config the checkpoint was trained with"
    )
    stiffer = SimulatedData(MassSpring(alpha=2.0), cache_dir=str(tmp_path))
    with pytest.raises(
        ValueError,
        match=r"MassSpring\(alpha=1.0\) but the config's data is "
        r"hnn_pl.systems.mass_spring.MassSpring\(alpha=2.0\)",
    ):
        _model().load_trained(ckpt, stiffer)
    check_same_system(ckpt, SimulatedData(MassSpring(), cache_dir=str(tmp_path)), "C")
    with pytest.raises(ValueError, match="trained on hnn_pl.systems.mass_spring.MassSpring but"):
        _fit(
            _model(),
            SimulatedData(
                Pendulum(), n_trajectories=6, n_points=8, window=3, cache_dir=str(tmp_path)
            ),
            steps=3,
            ckpt_path=path,
        )


# ------------------------------------------------------------------ options act or are refused


@pytest.mark.parametrize(
    "option",
    [
        {"learned_states": "sample"},
        {"continuity_weight": 1.0},
        {"substeps": 2},
        {"traj_method": "leapfrog"},
        {"state_weight": 0.5},
        {"reinit_states": True},
    ],
)
def test_trajectory_options_with_the_derivative_objective_are_refused(option):
    ((name, value),) = option.items()
    with pytest.raises(ValueError) as err:
        HNN(objective="derivative", **option)
    expected = (
        f"model.init_args {name}={value!r}: only the trajectory objective uses them, and "
        "objective is 'derivative': remove them, or set model.init_args.objective: trajectory"
    )
    assert _one_line(err) == expected
    HNN(**{"objective": "trajectory", "learned_states": "sample", **option})
    auto = HNN(**{"learned_states": "sample", **option})  # objective "auto": by the data
    with pytest.raises(ValueError) as err:
        auto.resolve_objective(SimpleNamespace(window=None))
    assert _one_line(err) == expected.replace(f"{name}={value!r}", _unused(option))


def _unused(option: dict) -> str:
    """The options :func:`refuse_unused_options` names for ``learned_states: sample``
    plus ``option`` under the derivative objective."""
    given = {"learned_states": "sample", **option}
    return ", ".join(f"{k}={given[k]!r}" for k in TRAJECTORY_OPTIONS if k in given)


def test_the_objective_follows_the_data_unless_given():
    """``objective: auto`` (the default) is the trajectory objective for data serving
    windows and the derivative one otherwise, recorded in the hparams; given, it stays."""
    model = HNN(hidden_dim=8)
    assert model.objective == model.hparams.objective == "auto"
    model.resolve_objective(SimpleNamespace(window=3))
    assert model.objective == model.hparams.objective == "trajectory"
    assert model.hparams_initial.objective == "trajectory"
    model.resolve_objective(SimpleNamespace(window=None))  # resolved once: kept
    assert model.objective == "trajectory"
    plain = HNN(hidden_dim=8)
    plain.resolve_objective(SimpleNamespace(window=None))
    assert plain.objective == plain.hparams.objective == "derivative"
    given = HNN(hidden_dim=8, objective="derivative")
    given.resolve_objective(SimpleNamespace(window=3))
    assert given.objective == "derivative"


def test_defaults_of_trajectory_options_pass_and_states_options_need_learned_states():
    HNN(substeps=1, traj_method="rk4", state_weight=1.0, continuity_weight=0.0)
    with pytest.raises(ValueError) as err:
        HNN(objective="trajectory", state_weight=2.0, reinit_states=True)
    assert _one_line(err).startswith(
        "model.init_args state_weight=2.0, reinit_states=True: they act on learned states, and "
        "learned_states is 'none'"
    )


@pytest.mark.parametrize(
    ("cls", "kwargs", "message"),
    [
        (HNN, {"state_weight": math.inf}, "state_weight must be finite and >= 0: inf"),
        (HNN, {"state_weight": math.nan}, "state_weight must be finite and >= 0: nan"),
        (HNN, {"state_weight": -1.0}, "state_weight must be finite and >= 0: -1.0"),
        (HNN, {"continuity_weight": math.inf}, "continuity_weight must be finite and >= 0"),
        (HNN, {"substeps": 0}, "substeps must be an integer >= 1: 0"),
        (HNN, {"substeps": 1.5}, "substeps must be an integer >= 1: 1.5"),
        (HNN, {"hidden_dim": 0}, "hidden_dim and n_hidden >= 1"),
        (HNN, {"inner_steps": 0}, "inner_steps >= 1"),
        (HNN, {"warmup_steps": -1}, "warmup_steps >= 0"),
        (HNN, {"weight_decay": math.inf}, "weight_decay must be finite and >= 0: inf"),
        (HNN, {"lr": math.nan}, "lr must be finite and > 0"),
        (HNN, {"grad_clip": math.inf}, "grad_clip must be finite and > 0, or null: inf"),
        (AutoencoderHNN, {"hnn_weight": math.inf}, "hnn_weight must be finite and >= 0: inf"),
        (AutoencoderHNN, {"input_noise": -0.1}, "input_noise must be finite and >= 0: -0.1"),
        (AutoencoderHNN, {"field_weight_decay": math.nan}, "field_weight_decay must be finite"),
        (AutoencoderHNN, {"frame_dt": 0.0}, "frame_dt must be finite and > 0: 0.0"),
        (AutoencoderHNN, {"field_n_hidden": 0}, "field_n_hidden must be an integer >= 1: 0"),
    ],
)
def test_numeric_model_options_are_checked(cls, kwargs, message):
    if cls is HNN and set(kwargs) & {"state_weight", "continuity_weight", "substeps"}:
        kwargs = {"objective": "trajectory", "learned_states": "sample", **kwargs}
    with pytest.raises(ValueError) as err:
        cls(**kwargs)
    assert message in _one_line(err)


def test_the_model_refuses_data_it_would_not_use(tmp_path):
    thinned = _dm(tmp_path, window=None, keep_fraction=0.5)
    with pytest.raises(ValueError) as err:
        HNN().check_data(thinned)
    assert _one_line(err).startswith(
        "data.init_args.keep_fraction: 0.5 thins only the observed trajectories, which the "
        "derivative objective does not use"
    )
    with pytest.raises(ValueError, match="keep_fraction: 0.5 thins only"):  # setup checks too
        _fit(HNN(hidden_dim=8), thinned)
    with pytest.raises(ValueError, match="window: 3 serves windows, which only the trajectory"):
        HNN(objective="derivative").check_data(_dm(tmp_path))
    HNN().check_data(_dm(tmp_path))  # "auto": the windows make it the trajectory objective
    with pytest.raises(ValueError, match="objective: trajectory needs windows"):
        _model().check_data(_dm(tmp_path, window=None))
    _model().check_data(_dm(tmp_path, keep_fraction=0.5))
    HNN().check_data(_dm(tmp_path, window=None))


# ------------------------------------------------------------------ the CLI's options


def test_options_given_on_the_command_line_are_found():
    argv = [
        "fit",
        "--config",
        "x.yaml",
        "--model.init_args.lr=0.5",
        "--model.init_args.n_hidden",
        "3",
        "--model.hidden_dim=4",
        "--model.help",
        "HNN",
        "--model",
        "HNN",
        "--data.init_args.seed=1",
        "--model.init_args.objective=trajectory",
    ]
    assert given_model_options(argv) == {"lr", "n_hidden", "hidden_dim", "objective"}


def test_checkpoint_options_are_restored_unless_given_and_refused_if_changed():
    from types import SimpleNamespace

    ckpt = {
        "hyper_parameters": {
            "lr": 3e-3,
            "hidden_dim": 200,
            "objective": "trajectory",
            "reinit_states": False,
            "radius": [0.1, 1.0],
        }
    }
    config = SimpleNamespace(
        lr=0.5, hidden_dim=50, objective="trajectory", reinit_states=True, radius=(0.1, 1.0)
    )
    with pytest.raises(ValueError) as err:
        refuse_changed_options(ckpt, config, {"lr", "reinit_states"}, "checkpoint C")
    assert _one_line(err) == (
        "--model.init_args.lr=0.5: checkpoint C was trained with lr=0.003, and a run from a "
        "checkpoint keeps the options it was trained with: remove the option, or fit anew "
        "without --ckpt_path"
    )
    refuse_changed_options(ckpt, config, {"reinit_states", "radius"}, "checkpoint C")
    restored = checkpoint_init_args(ckpt, config, {"reinit_states"})
    assert restored == {
        "lr": 3e-3,
        "hidden_dim": 200,
        "objective": "trajectory",
        "radius": [0.1, 1.0],
    }
    config.objective = "derivative"  # from the config file: restoring it would mislead
    with pytest.raises(
        ValueError,
        match="was trained with objective='trajectory' but the config sets objective: 'derivative'",
    ):
        refuse_changed_options(ckpt, config, set(), "checkpoint C")


# ------------------------------------------------------------------ bump


def test_bump_works_on_a_run_with_learned_states(tmp_path, monkeypatch):
    """``fit --config spring_traj.yaml --trainer.max_steps=2`` then ``bump`` on its run."""
    from hnn_pl.commands.main import main

    monkeypatch.chdir(tmp_path)
    fit = ["fit", "--config", "spring_traj.yaml", "--trainer.max_steps=2"]
    main([*fit, "--trainer.enable_progress_bar=false"])
    run = tmp_path / "lightning_logs" / "spring_traj_hnn"
    argv = ["bump", "--config", "spring_traj.yaml", "--ckpt_path", str(run)]
    with pytest.raises(SystemExit) as info:
        main([*argv, "--t_end", "1", "--n_points", "5", "--starts", "2"])
    assert info.value.code == 0
    saved = torch.load(run / "version_0" / "bump.pt", weights_only=True)
    moved = saved["after"]["h"][0] - saved["before"]["h"][0]
    torch.testing.assert_close(moved, torch.full_like(moved, saved["delta"]), rtol=0, atol=1e-7)
