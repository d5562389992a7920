"""Callbacks: thin schedulers around the rollout engine (:mod:`hnn_pl.rollouts`)."""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.callbacks import BasePredictionWriter, ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger

from hnn_pl import rollouts, tasks
from hnn_pl.protocols import Protocol
from hnn_pl.safe_io import save_atomic


def task_protocol(task: str, protocol: str, overrides: dict[str, Any] | None) -> Protocol:
    """``tasks.get(task).protocol(protocol)`` with ``overrides``, checked now
    (``ValueError`` on an unknown task, protocol or field, or a bad value)."""
    try:
        p = tasks.get(task).protocol(protocol)
    except KeyError as e:
        raise ValueError(e.args[0]) from None
    if not isinstance(p, Protocol):
        raise ValueError(
            f"the {protocol!r} protocol of task {task!r} is scipy's reference procedure "
            "(hnn_pl.evaluate.evaluate_reference), not a rollout protocol; use 'clean'"
        )
    try:
        return p.replace(**(overrides or {}))
    except TypeError as e:
        raise ValueError(f"overrides {overrides}: {e}") from None


class FinalCheckpoint(ModelCheckpoint):
    """Lightning's ``ModelCheckpoint`` (default ``save_last=True``) that also saves at
    the end of ``fit``, so ``last.ckpt`` is the model at the final step.

    Lightning saves after validation or at an epoch's end; a fit that stops at
    ``max_steps`` inside an epoch, or between two validations
    (``check_val_every_n_epoch`` > 1), would otherwise leave ``last.ckpt`` at an
    earlier step than the metrics logged at the end of the fit. No ``monitor``: the
    validation split is the test split (there is no model selection), so the kept
    checkpoint is the latest one (``epoch=E-step=S.ckpt``) and ``last.ckpt``.
    The CLI adds one to every fit unless checkpointing is off or the config names
    its own checkpoint callback. Arguments: Lightning's.
    """

    def __init__(self, *args: Any, save_last: bool | str | None = True, **kwargs: Any) -> None:
        super().__init__(*args, save_last=save_last, **kwargs)

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.fast_dev_run or trainer.global_step == self._last_global_step_saved:
            return super().on_train_end(trainer, pl_module)
        candidates = self._monitor_candidates(trainer)
        self._save_topk_checkpoint(trainer, candidates)
        self._save_last_checkpoint(trainer, candidates)


class RolloutCallback(Callback):
    """Roll the model out from the held-out starts under a task's protocol and log it.

    Every ``every_n_epochs`` epochs and at the end of ``fit`` (only with a logger:
    nothing is computed that is not recorded), and in ``test``, rank zero:
    :func:`hnn_pl.rollouts.evaluate` on all held-out starts in one batch, logged as
    ``rollout/<metric>`` (``energy_mse`` = ``mean_{t,b} (E(y_true) − E(y_pred))²``,
    ``state_mse``, ``motion_error``, ``valid_time``, ``conserved_drift`` (HNN),
    ``field_error`` (state models: :func:`hnn_pl.rollouts.field_error`, the relative
    error of ``f_θ`` on the true states); pixel: ``pixel_mse``,
    ``latent_mse``, ``probe_mse``) over the rows that stayed finite, and
    ``rollout/diverged_rows``: a diverging row stops alone and the fit goes on.
    With ``log_images`` and TensorBoard: ``rollout/phase_portrait``,
    ``rollout/energy``, pixel ``rollout/frames``.

    Args:
        task: a name in :data:`hnn_pl.tasks.TASKS`.
        protocol: ``"clean"`` or ``"reference"`` (pixel only; the state tasks'
            reference is scipy's procedure, run by ``reproduce``).
        every_n_epochs: period during training; ``0``: only at the end of fit.
        log_images: draw the figures.
        overrides: protocol fields to change, e.g. ``{method: rk4, step_size: 0.05}``.
    """

    def __init__(
        self,
        task: str = "spring",
        protocol: str = "clean",
        every_n_epochs: int = 100,
        log_images: bool = True,
        overrides: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        if every_n_epochs < 0:
            raise ValueError(f"every_n_epochs must be >= 0, got {every_n_epochs}")
        self.protocol = task_protocol(task, protocol, overrides)
        self.every_n_epochs = every_n_epochs
        self.log_images = log_images
        self._last_logged_step = -1

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        """Record what tells runs apart in every logger's hyperparameters: the model's
        class, the system with its parameters, the rollout protocol."""
        cls = type(pl_module)
        dm_hparams = getattr(trainer.datamodule, "hparams", {})
        run = {
            "model_class": f"{cls.__module__}.{cls.__qualname__}",
            "system": dm_hparams.get("system", type(trainer.datamodule).__name__),
            "rollout_protocol": vars(self.protocol),
        }
        for logger in trainer.loggers:
            logger.log_hyperparams(run)

    def _images(self, trainer: Trainer, r: rollouts.Rollout) -> None:
        if not (self.log_images and isinstance(trainer.logger, TensorBoardLogger)):
            return
        from hnn_pl import plotting

        writer, step = trainer.logger.experiment, trainer.global_step
        for tag, fig in plotting.figures(r).items():
            writer.add_figure(tag, fig, step)
        if r.is_pixel:
            writer.add_figure("rollout/frames", plotting.frames_figure(r), step)

    def _log_during_fit(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if not (trainer.is_global_zero and trainer.loggers):
            return
        if trainer.global_step == self._last_logged_step:
            return
        self._last_logged_step = trainer.global_step
        metrics, r = rollouts.evaluate(pl_module, trainer.datamodule, self.protocol)
        tagged = {f"rollout/{k}": v for k, v in metrics.items()}
        for logger in trainer.loggers:
            logger.log_metrics(tagged, step=trainer.global_step)
        self._images(trainer, r)

    def on_train_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if self.every_n_epochs and (trainer.current_epoch + 1) % self.every_n_epochs == 0:
            self._log_during_fit(trainer, pl_module)

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        self._log_during_fit(trainer, pl_module)

    def on_test_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        metrics, r = rollouts.evaluate(pl_module, trainer.datamodule, self.protocol)
        for k, v in metrics.items():
            pl_module.log(f"rollout/{k}", v, rank_zero_only=True)
        self._images(trainer, r)


class PixelRolloutCallback(RolloutCallback):
    """:class:`RolloutCallback` with the pixel task's protocol (200-frame latent
    rollouts of every held-out trajectory, decoded and probed) and a period of 25
    epochs. Arguments as :class:`RolloutCallback`."""

    def __init__(
        self,
        task: str = "pixel",
        protocol: str = "clean",
        every_n_epochs: int = 25,
        log_images: bool = True,
        overrides: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(task, protocol, every_n_epochs, log_images, overrides)


class RolloutWriter(BasePredictionWriter):
    """``predict`` that answers: rollouts written to a file beside the run.

    At the end of ``predict`` (rank zero) the model is rolled out under the task's
    protocol from the held-out starts, or from ``starts`` (a ``torch.save``-d
    ``(B, D)`` tensor; pixel: frame pairs), and ``torch.save``-d as a dict:
    held-out: ``t (T,)``, ``y_true``/``y_pred (T, B, D)``, ``energy_true``/
    ``energy_pred (T, B)``, ``h_pred`` (HNN), ``metrics``; pixel also
    ``frames_true``/``frames_pred``, ``z_pred`` (``y`` are the probe's ``(q, p)``).
    Given starts: ``t``, ``y``, ``h``, ``energy`` (state), ``frames`` (pixel), each
    row's ``status`` and ``t_stop`` (rows that stopped early are counted in the printed
    line; the CLI refuses a file of starts that is not a finite ``(B, D)`` tensor). The
    ``predict_step`` outputs (state models: ``dy/dt`` at the held-out states; pixel:
    their latent codes) stay in ``trainer.predict_loop.predictions``, not in the
    file. The file goes to the checkpoint's run directory (``…/version_N/``), else
    the logger's, else the working directory, and its path is printed.

    Args:
        task, protocol, overrides: the protocol, as :class:`RolloutCallback`.
        starts: a file of starts, or ``None`` for the held-out ones.
        filename: the file's name.
    """

    def __init__(
        self,
        task: str = "spring",
        protocol: str = "clean",
        overrides: dict[str, Any] | None = None,
        starts: str | None = None,
        filename: str = "rollouts.pt",
    ) -> None:
        super().__init__(write_interval="epoch")
        warnings.filterwarnings("ignore", message=".*infer the batch indices.*")
        self.protocol = task_protocol(task, protocol, overrides)
        self.starts = starts
        self.filename = filename
        self.path: Path | None = None

    def _directory(self, trainer: Trainer) -> Path:
        if trainer.ckpt_path:
            ckpt_dir = Path(trainer.ckpt_path).parent
            return ckpt_dir.parent if ckpt_dir.name == "checkpoints" else ckpt_dir
        if trainer.logger is not None and trainer.log_dir is not None:
            return Path(trainer.log_dir)
        return Path.cwd()

    def _given_starts(self, pl_module: LightningModule, dm: Any) -> dict[str, Any]:
        y0 = torch.load(self.starts, weights_only=True)
        p = self.protocol
        if rollouts.is_pixel_model(pl_module):
            t = torch.arange(p.n_points or 200, dtype=torch.float64) * pl_module.frame_dt
            energy = None
        else:
            t = torch.linspace(0.0, p.t_end or 1.0, p.n_points or 100, dtype=torch.float64)
            energy = dm.energy if getattr(dm, "has_energy", True) else None
        out = rollouts.rollout(pl_module, y0, t, dtype=p.dtype, energy=energy, **p.solver_kwargs())
        return out.as_dict()

    def write_on_epoch_end(
        self,
        trainer: Trainer,
        pl_module: LightningModule,
        predictions: Any,
        batch_indices: Any,
    ) -> None:
        if not trainer.is_global_zero:
            return
        dm = trainer.datamodule
        if self.starts is not None:
            payload = self._given_starts(pl_module, dm)
        else:
            metrics, r = rollouts.evaluate(pl_module, dm, self.protocol)
            payload = {
                "t": r.t,
                "y_true": r.y_true,
                "y_pred": r.y_pred,
                "energy_true": r.e_true,
                "energy_pred": r.e_pred,
                "h_pred": r.h_pred,
                "metrics": metrics,
                "frames_true": r.x_true,
                "frames_pred": r.x_pred,
                "z_pred": r.z_pred,
            }
        payload = {k: v.cpu() if torch.is_tensor(v) else v for k, v in payload.items()}
        payload = {k: v for k, v in payload.items() if v is not None}
        directory = self._directory(trainer)
        directory.mkdir(parents=True, exist_ok=True)
        self.path = directory / self.filename
        save_atomic(payload, self.path)
        shape = tuple(payload.get("y_pred", payload.get("y")).shape)
        status = payload.get("status")
        stopped = int((status != 0).sum()) if status is not None else 0
        note = f"; {stopped} of {len(status)} rows stopped early (see 'status')" if stopped else ""
        print(f"wrote rollouts {shape} (T, B, D) to {self.path}{note}", flush=True)


class TimeToAccuracy(Callback):
    """Training time until the model reaches the paper's accuracy *and* the paper
    recipe's motion.

    Every ``every_n_steps`` optimiser steps (rank zero) the model is scored on its
    task's reference protocol (state tasks: :func:`hnn_pl.evaluate.score_reference`,
    by default batched float64 ``dopri5`` at the protocol's ≈1e-6 accuracy, truth
    prepared once in ``setup``; pixel: the engine's latent rollout and probe).
    A check passes when all of:

    - the energy MSE on the paper's protocol is ≤ ``target`` (the published HNN value);
    - :func:`hnn_pl.rollouts.motion_error` ≤ ``max_motion_error`` (1 for a model
      that never moves: a still state conserves any energy);
    - the state MSE on the task's clean protocol (:func:`hnn_pl.rollouts.run`
      without the error floors, truth computed once) is ≤ ``state_target``, the
      paper recipe's median over seeds (:attr:`hnn_pl.tasks.Task.paper_motion`). It
      is computed only at checks that pass the first two, until the first pass.

    Logged: ``tta/energy_mse``, ``tta/motion_error``, ``tta/state_mse`` (when
    computed); once passed, ``tta/seconds`` (training time since ``setup``, scoring
    excluded) and ``tta/step``; ``stop`` ends the fit there. Afterwards
    :attr:`reached` is ``{"step", "seconds", "wall_seconds", "energy_mse",
    "motion_error", "state_mse"}`` or ``None``; :attr:`history` every ``(step,
    seconds, energy_mse, motion_error, state_mse)`` (``state_mse`` NaN where not
    computed); :attr:`scoring_seconds` the scoring's own cost.

    Args:
        task: a name in :data:`hnn_pl.tasks.TASKS`.
        target: the energy MSE to reach (``None``: the published HNN value).
        every_n_steps: scoring period in optimiser steps.
        stop: end the fit when the target is reached.
        solver: ``"torch"`` or ``"scipy"`` (the published RK45; slower).
        max_motion_error: the largest motion error that counts (0.25: a model at
            half the true speed; trained models measure 0.001–0.07 on the
            reference protocols, untrained ones ≈ 1).
        state_target: the clean state MSE to reach (``None``: the paper recipe's
            median from the registry; ``math.inf`` or a task without one: no
            state condition).
    """

    def __init__(
        self,
        task: str = "spring",
        target: float | None = None,
        every_n_steps: int = 50,
        stop: bool = False,
        solver: str = "torch",
        max_motion_error: float = 0.25,
        state_target: float | None = None,
    ) -> None:
        super().__init__()
        self.task = tasks.get(task)
        if not max_motion_error > 0:
            raise ValueError(f"max_motion_error must be > 0, got {max_motion_error}")
        self.max_motion_error = float(max_motion_error)
        if solver not in ("torch", "scipy"):
            raise ValueError(f"solver must be 'torch' or 'scipy', got {solver!r}")
        if every_n_steps < 1:
            raise ValueError(f"every_n_steps must be >= 1, got {every_n_steps}")
        self.target = self.task.published["hnn"].energy_mse if target is None else float(target)
        if state_target is None:
            paper = self.task.paper_motion
            state_target = math.inf if paper is None else paper.state_mse
        if not state_target > 0:
            raise ValueError(f"state_target must be > 0, got {state_target}")
        self.state_target = float(state_target)
        self.every_n_steps, self.stop, self.solver = every_n_steps, stop, solver
        self.reached: dict[str, float] | None = None
        self.history: list[tuple[int, float, float, float, float]] = []
        self.scoring_seconds = 0.0

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        from hnn_pl.evaluate import reference_case, score_reference

        dm = trainer.datamodule
        dm.setup(stage)
        if self.task.kind == "state":
            case = reference_case(dm, self.task.reference)
            self._score = lambda m: score_reference(m, case, self.solver)
        else:
            self._score = lambda m: rollouts.evaluate(m, dm, self.task.reference)[0]
        self._state = lambda m: rollouts.score(rollouts.run(m, dm, self.task.clean, floors=False))
        self._next = self.every_n_steps
        self._start = time.perf_counter()
        self.scoring_seconds = 0.0

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *args) -> None:
        step = trainer.global_step
        if step < self._next or not trainer.is_global_zero:
            return
        self._next = step + self.every_n_steps - step % self.every_n_steps
        t0 = time.perf_counter()
        was_training = pl_module.training
        pl_module.eval()
        m = self._score(pl_module)
        energy, motion, state = m["energy_mse"], m["motion_error"], math.nan
        passed = energy <= self.target and motion <= self.max_motion_error
        if passed and self.reached is None and math.isfinite(self.state_target):
            state = self._state(pl_module)["state_mse"]
            passed = state <= self.state_target
        pl_module.train(was_training)
        seconds = t0 - self._start - self.scoring_seconds
        self.scoring_seconds += time.perf_counter() - t0
        self.history.append((step, seconds, energy, motion, state))
        metrics = {"tta/energy_mse": energy, "tta/motion_error": motion}
        if not math.isnan(state):
            metrics["tta/state_mse"] = state
        if self.reached is None and passed:
            wall = t0 - self._start
            self.reached = {"step": step, "seconds": seconds, "wall_seconds": wall}
            self.reached.update(energy_mse=energy, motion_error=motion, state_mse=state)
            metrics.update({"tta/seconds": seconds, "tta/step": float(step)})
            trainer.should_stop = trainer.should_stop or self.stop
        for logger in trainer.loggers:
            logger.log_metrics(metrics, step=step)
