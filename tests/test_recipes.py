"""Training recipes: optimisers, schedules, inner steps, non-finite guards, time to accuracy."""

from __future__ import annotations

import math

import lightning as L
import pytest
import torch

from hnn_pl import evaluation
from hnn_pl.commands.cli import QUIET_TRAINER
from hnn_pl.data import SimulatedData
from hnn_pl.experiments.tta import TimeToAccuracy
from hnn_pl.models import HNN, Baseline
from hnn_pl.systems import MassSpring


def _dm(tmp_path, **kw) -> SimulatedData:
    kw = {"n_trajectories": 6, "n_points": 10, "full_batch_steps": 4, "seed": 0, **kw}
    return SimulatedData(MassSpring(), cache_dir=str(tmp_path), dtype="float64", **kw)


def _fit(model, dm, steps: int, callbacks=()) -> L.Trainer:
    quiet = {**QUIET_TRAINER, "callbacks": list(callbacks)}
    trainer = L.Trainer(max_steps=steps, precision="64-true", **quiet)
    trainer.fit(model, dm)
    return trainer


def _model(cls=HNN, **kw):
    torch.manual_seed(0)
    return cls(input_dim=2, hidden_dim=16, **kw)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"lr": math.inf}, "lr"),
        ({"lr": 0.0}, "lr"),
        ({"weight_decay": -1.0}, "weight_decay"),
        ({"optimizer": "sgd"}, "optimizer"),
        ({"schedule": "linear"}, "schedule"),
        ({"inner_steps": 0}, "inner_steps"),
        ({"grad_clip": 0.0}, "grad_clip"),
        ({"on_nonfinite": "ignore"}, "on_nonfinite"),
        ({"hidden_dim": 0}, "hidden_dim"),
        ({"polish_steps": -1}, "polish_steps"),
        ({"polish_steps": 2.0}, "polish_steps"),
    ],
)
def test_bad_recipe_options_fail_at_construction(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HNN(input_dim=2, **{"hidden_dim": 16, **kwargs})


def test_inner_steps_are_the_same_optimiser_steps_and_respect_max_steps(tmp_path):
    """Full batch: k steps per batch is the same training as one step per batch."""
    one = _model(weight_decay=1e-4)
    _fit(one, _dm(tmp_path), 7)
    many = _model(weight_decay=1e-4, inner_steps=5)
    trainer = _fit(many, _dm(tmp_path), 7)
    assert trainer.global_step == 7  # 5 + 2: the last batch is cut to max_steps
    for a, b in zip(one.parameters(), many.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("schedule", ["cosine", "onecycle"])
def test_schedules_decay_to_the_end_of_training(tmp_path, schedule):
    model = _model(lr=1e-2, schedule=schedule, warmup_steps=2 * (schedule == "cosine"))
    trainer = _fit(model, _dm(tmp_path), 20)
    lr_end = trainer.optimizers[0].param_groups[0]["lr"]
    assert lr_end < 1e-2 * 1e-3


@pytest.mark.parametrize("cls", [HNN, Baseline])
def test_lbfgs_fits_a_full_batch_faster_than_adam(tmp_path, cls):
    dm = _dm(tmp_path)
    dm.setup()

    def loss(m):
        with torch.no_grad():
            return float(torch.nn.functional.mse_loss(m(dm.x_train), dm.dx_train))

    adam = _model(cls).double()
    lbfgs = _model(cls, optimizer="lbfgs", lr=1.0, weight_decay=1e-4)
    start = loss(adam)
    _fit(adam, dm, 20)
    _fit(lbfgs, dm, 20)
    assert loss(lbfgs) < loss(adam) < start


class _Seen(HNN):
    """Records each objective evaluation's rows and whether it was polishing."""

    def training_loss(self, batch):
        self.seen.append((len(batch[0]), self.polishing))
        return super().training_loss(batch)


def test_polishing_ends_the_fit_with_lbfgs_on_the_whole_training_set(tmp_path):
    """The last ``polish_steps`` of ``max_steps`` are L-BFGS iterations on all the
    training rows (mini-batches of 8 before), of the squared error though the loss is
    ``l1``; the cosine schedule ends with the first optimiser's steps; the polished
    field fits the data better than the same fit stopped before polishing."""
    dm = _dm(tmp_path)
    dm.setup()
    rows = len(dm.x_train)
    kw = dict(loss="l1", lr=1e-2, schedule="cosine")
    polished = _model(_Seen, polish_steps=20, **kw)
    polished.seen = []
    trainer = _fit(polished, _dm(tmp_path, batch_size=8), 60)
    assert trainer.global_step == 60 and not polished.polishing
    adam, lbfgs = trainer.optimizers
    assert isinstance(lbfgs, torch.optim.LBFGS)
    assert lbfgs.state[lbfgs.param_groups[0]["params"][0]]["n_iter"] == 20
    assert adam.param_groups[0]["lr"] < 1e-2 * 1e-3  # the schedule spans the 40 steps
    first = [n for n, p in polished.seen if not p]
    assert set(first) == {8, rows % 8 or 8} and len(first) == 40
    polishing = [n for n, p in polished.seen if p]  # one or more evaluations an iteration
    assert set(polishing) == {rows} and len(polishing) >= 20
    plain = _model(_Seen, **kw)
    plain.seen = []
    _fit(plain, _dm(tmp_path, batch_size=8), 40)

    def loss(m):
        with torch.no_grad():
            return float(torch.nn.functional.mse_loss(m(dm.x_train), dm.dx_train))

    assert loss(polished) < 0.5 * loss(plain)


class _Tiny(HNN):
    """The objective scaled by 1e-12, as small as a trained field's and smaller."""

    def training_loss(self, batch):
        return {"loss": 1e-12 * super().training_loss(batch)["loss"]}


@pytest.mark.parametrize("optimizer", ["adam", "lbfgs"])
def test_polishing_moves_the_weights_however_small_the_objective(tmp_path, optimizer):
    """torch's default tolerances would stop L-BFGS before its first step here (a trained
    field's polishing did no more than that): every polishing step moves the weights."""
    one = _model(_Tiny, optimizer=optimizer)
    _fit(one, _dm(tmp_path), 1)
    more = _model(_Tiny, optimizer=optimizer, polish_steps=3)
    _fit(more, _dm(tmp_path), 4)
    moved = [not torch.equal(a, b) for a, b in zip(one.parameters(), more.parameters())]
    assert all(moved)


def test_polishing_is_lbfgs_with_its_whole_line_search(tmp_path):
    """P polishing steps reach the weights of one torch L-BFGS call of P iterations from
    where the first optimiser left them: the same line searches (a one-iteration step
    with torch's default ``max_eval`` had none, and kept its start whenever the first
    trial was no better), and no more evaluations of the objective than that call's
    (each step's opening evaluation, of the point the last line search ended on, is
    answered from the kept evaluations)."""
    polished = _model(_Seen, polish_steps=8, loss="l1", lr=1e-2)
    polished.seen = []
    _fit(polished, _dm(tmp_path), 10)
    start = _model(loss="l1", lr=1e-2)
    _fit(start, _dm(tmp_path), 2)  # early: its line searches take several evaluations
    dm = _dm(tmp_path)
    dm.setup()
    batch = dm.train_dataloader().tensors
    opt = torch.optim.LBFGS(
        list(start.parameters()),
        max_iter=8,
        max_eval=8 * 26,
        history_size=50,
        line_search_fn="strong_wolfe",
        tolerance_grad=0.0,
        tolerance_change=0.0,
    )

    def closure():
        opt.zero_grad()
        start.polishing = True
        loss = start.training_loss(batch)["loss"]
        start.polishing = False
        loss.backward()
        return loss

    opt.step(closure)
    evals = opt.state[opt._params[0]]["func_evals"]
    assert evals > 9  # some line searches took two or more
    assert sum(p for _, p in polished.seen) == evals
    for a, b in zip(polished.parameters(), start.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)


def test_polishing_stops_when_its_weights_stop_changing(tmp_path, monkeypatch):
    """In float32 L-BFGS's line search runs out of decrease; from then on every step
    repeats it from the same point. The fit stops at the first step that leaves the
    weights as they were, with the weights that running every remaining step ends on."""

    def fit(stop: bool) -> tuple[HNN, L.Trainer]:
        if not stop:
            monkeypatch.setattr(HNN, "_stop_polishing", lambda self: None)
        torch.manual_seed(0)
        model = HNN(input_dim=2, hidden_dim=8, polish_steps=380, lr=1e-2)
        kw = dict(n_trajectories=3, n_points=10, full_batch_steps=4, seed=0)
        dm = SimulatedData(MassSpring(), cache_dir=str(tmp_path), dtype="float32", **kw)
        trainer = L.Trainer(max_steps=400, precision="32-true", **QUIET_TRAINER)
        trainer.fit(model, dm)
        return model, trainer

    stopped, trainer = fit(stop=True)
    assert 20 < stopped.polish_stopped_at == trainer.global_step < 400
    full, trainer = fit(stop=False)
    assert trainer.global_step == 400 and full.polish_stopped_at is None
    for a, b in zip(stopped.parameters(), full.parameters(), strict=True):
        assert torch.equal(a, b)


def test_a_run_shorter_than_its_polishing_polishes_its_second_half(tmp_path):
    """A smoke run of a polishing config (``max_steps`` ≤ ``polish_steps``) still runs,
    says so, and polishes its last half; without ``max_steps`` polishing is refused."""
    model = _model(_Seen, polish_steps=50)
    model.seen = []
    with pytest.warns(UserWarning, match="polish_steps=50 is not less than .*=5: the last 2"):
        trainer = _fit(model, _dm(tmp_path), 5)
    assert trainer.global_step == 5
    assert [p for _, p in model.seen][:3] == [False] * 3 and all(p for _, p in model.seen[3:])
    trainer = L.Trainer(max_epochs=1, precision="64-true", **QUIET_TRAINER)
    with pytest.raises(ValueError, match="polish_steps=50 needs trainer.max_steps"):
        trainer.fit(_model(polish_steps=50), _dm(tmp_path))


def test_a_non_finite_loss_stops_before_the_update(tmp_path):
    dm = _dm(tmp_path)
    dm.setup()
    dm.x_train[3, 0] = math.nan
    model = _model()
    before = [p.detach().clone() for p in model.parameters()]
    with pytest.raises(FloatingPointError, match="at step 0.*last good checkpoint"):
        _fit(model, dm, 5)
    assert all(torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))


class _InfiniteGradient(HNN):
    """A finite loss whose gradient is not: ``√(0·w)`` has value 0 and slope ``∞·0``."""

    def training_loss(self, batch):
        parts = super().training_loss(batch)
        w = self.field.net.out.weight
        return {"loss": parts["loss"] + torch.sqrt(0.0 * w.sum())}


@pytest.mark.parametrize("optimizer", ["adam", "lbfgs"])
def test_a_non_finite_gradient_of_a_finite_loss_stops_before_the_update(tmp_path, optimizer):
    """One update with a non-finite gradient makes every weight NaN, on the run's last step
    too (a diverging MechanicalLNN on chain2 wrote such a checkpoint): stopped first."""
    model = _model(_InfiniteGradient, optimizer=optimizer)
    before = [p.detach().clone() for p in model.parameters()]
    with pytest.raises(FloatingPointError, match="non-finite gradient .* at step 0"):
        _fit(model, _dm(tmp_path), 1)
    assert all(torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))


def test_skip_mode_drops_non_finite_steps_then_gives_up(tmp_path):
    dm = _dm(tmp_path)
    dm.setup()
    dm.x_train[3, 0] = math.nan
    model = _model(on_nonfinite="skip")
    before = [p.detach().clone() for p in model.parameters()]
    with pytest.raises(FloatingPointError, match="after 10 skipped steps"):
        _fit(model, dm, 5)
    assert all(torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))


def test_grad_clip_bounds_the_update(tmp_path):
    model = _model(Baseline, optimizer="adamw", lr=1e-3, grad_clip=1e-8)
    before = [p.detach().clone() for p in model.parameters()]
    _fit(model, _dm(tmp_path), 1)
    # Adam normalises the clipped gradient, so the first step still moves by ≈ lr
    moved = max(
        float((a - b.detach()).abs().max()) for a, b in zip(before, model.parameters(), strict=True)
    )
    assert 0 < moved <= 1.01e-3


def test_time_to_accuracy_records_the_first_step_at_the_target_and_can_stop(tmp_path):
    dm = _dm(tmp_path)
    never = TimeToAccuracy("spring", target=0.0, every_n_steps=3)
    _fit(_model(), dm, 9, [never])
    assert never.reached is None and [h[0] for h in never.history] == [3, 6, 9]
    assert all(h[2] > 0 for h in never.history)
    at_once = TimeToAccuracy(
        "spring", target=1e9, every_n_steps=3, stop=True, max_motion_error=9, state_target=1e9
    )
    trainer = _fit(_model(), dm, 9, [at_once])
    assert trainer.global_step == 3 and at_once.reached["step"] == 3
    assert 0 < at_once.reached["seconds"] <= at_once.reached["wall_seconds"]
    assert 0 < at_once.reached["state_mse"] < 1e9


def test_time_to_accuracy_needs_the_state_target_too(tmp_path):
    """Energy and motion pass (targets 1e9), the clean state MSE cannot reach 1e-30."""
    strict = TimeToAccuracy(
        "spring", target=1e9, every_n_steps=3, max_motion_error=9, state_target=1e-30
    )
    _fit(_model(), _dm(tmp_path), 6, [strict])
    assert strict.reached is None and [h[0] for h in strict.history] == [3, 6]
    assert all(1e-30 < h[4] < math.inf for h in strict.history)


def test_time_to_accuracy_refuses_a_field_that_does_not_move(tmp_path):
    """A still state conserves every energy: energy MSE ≈ 0, yet the motion is wrong."""
    dm = _dm(tmp_path)
    model = _model(lr=1e-12)
    still = TimeToAccuracy("spring", target=1e-9, every_n_steps=1, max_motion_error=0.25)
    with torch.no_grad():
        for p in model.field.parameters():
            p.mul_(1e-6)
    _fit(model, dm, 1, [still])
    (_, _, energy, motion, _), *_ = still.history
    assert energy < 1e-9 and motion == pytest.approx(1.0, abs=1e-3) and still.reached is None


def test_time_to_accuracy_scores_like_the_published_procedure(tmp_path):
    """The callback's batched torch rollout agrees with scipy's RK45 (≈1e-6 accurate)."""
    dm = _dm(tmp_path)
    dm.setup()
    model = _model()
    _fit(model, dm, 30)
    case = evaluation.reference_case(dm, evaluation.task_protocol("spring", "reference"))
    torch_mse = evaluation.score(case.run(model, "torch"))["energy_mse"]
    scipy_mse = evaluation.score(case.run(model, "scipy"))["energy_mse"]
    assert torch_mse == pytest.approx(scipy_mse, rel=1e-3)


def test_data_seed_follows_the_run_seed_unless_pinned(tmp_path):
    L.seed_everything(3)
    follows, pinned = _dm(tmp_path, seed=None), _dm(tmp_path, seed=0)
    assert (follows.seed, pinned.seed) == (3, 0)
    follows.setup()
    pinned.setup()
    assert not torch.equal(follows.x_train, pinned.x_train)
