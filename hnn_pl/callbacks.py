"""Callbacks: thin schedulers around the evaluation (:mod:`hnn_pl.evaluation`), and a
progress bar that counts optimiser steps."""

from __future__ import annotations

import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.callbacks import BasePredictionWriter, ModelCheckpoint, TQDMProgressBar
from lightning.pytorch.loggers import TensorBoardLogger

from hnn_pl.evaluation import (
    Rollout,
    data_protocol,
    evaluate,
    rollout,
    task_protocol,
    view_of,
)
from hnn_pl.loggers import run_directory
from hnn_pl.safe_io import save_atomic, torch_load


def check_starts_file(path: str, width: int) -> None:
    """Refuse (``ValueError``, one line) a ``predict`` file of starts that is missing, not
    a tensor, not ``(B, width)`` or not finite; or, for a positions window (a ``.csv`` or
    a saved dict, :func:`~hnn_pl.evaluation.observer.read_positions_window`), one the
    observer cannot read with ``k = width / 2``."""
    from hnn_pl.evaluation.observer import read_positions_window

    if not Path(path).is_file():
        raise ValueError(f"starts {path}: no such file")
    if Path(path).suffix == ".csv":
        read_positions_window(path, width // 2)
        return
    try:
        y0 = torch_load(path)
    except Exception:  # noqa: BLE001 - any unreadable file is the same user error
        raise ValueError(f"starts {path}: cannot be read as a torch-saved tensor") from None
    if isinstance(y0, dict):
        read_positions_window(path, width // 2)
        return
    if not torch.is_tensor(y0) or not y0.is_floating_point():
        kind = f"{y0.dtype} tensor" if torch.is_tensor(y0) else type(y0).__name__
        raise ValueError(
            f"starts {path}: holds a {kind}; expected a float tensor (B, {width}) or a "
            f'positions window {{"q": (B, M, {width // 2}), "t": (M,)}}'
        )
    if y0.ndim != 2 or y0.shape[1] != width or y0.shape[0] == 0:
        raise ValueError(
            f"starts {path}: shape {tuple(y0.shape)}; the model's states need (B, {width})"
        )
    bad = ~torch.isfinite(y0).all(-1)
    if bool(bad.any()):
        rows = bad.nonzero().flatten().tolist()
        raise ValueError(
            f"starts {path}: {len(rows)} of {y0.shape[0]} rows are not finite (rows "
            f"{rows[:5]}{'...' if len(rows) > 5 else ''})"
        )


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


class StepProgressBar(TQDMProgressBar):
    """Lightning's progress bar, counting optimiser steps over the whole fit
    (``trainer.global_step`` of ``max_steps``) instead of each epoch's batches: a model
    taking ``inner_steps`` steps per batch (:class:`~hnn_pl.models.recipe.RecipeModel`)
    shows ``300/300 step`` at the end of a 300-step fit, not 15 ticks per epoch. The bar
    is closed when training ends, before the callbacks' final work (a final rollout is
    then its own step, :func:`shown_as_step`), if it comes first in the callbacks.
    Arguments: Lightning's."""

    def init_train_tqdm(self):
        bar = super().init_train_tqdm()
        bar.unit = "step"
        return bar

    def on_train_epoch_start(self, trainer: Trainer, *_: Any) -> None:
        bar = self.train_progress_bar
        bar.total = trainer.max_steps if trainer.max_steps > 0 else None
        bar.n = trainer.global_step  # a resumed fit starts where it stopped
        bar.set_description(f"Epoch {trainer.current_epoch}")

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *_: Any) -> None:
        bar = self.train_progress_bar
        if bar is not None and not bar.disable and trainer.global_step != bar.n:
            bar.n = trainer.global_step
            bar.set_postfix(self.get_metrics(trainer, pl_module))  # refreshes


@contextmanager
def shown_as_step(trainer: Trainer, description: str) -> Iterator[None]:
    """A piece of work shown as a one-step bar of its own (``description: 1/1 [time]``)
    when ``trainer`` shows a progress bar, else nothing."""
    bar = trainer.progress_bar_callback
    if not isinstance(bar, TQDMProgressBar) or not bar.is_enabled:
        yield
        return
    from tqdm import tqdm

    fmt = "{desc}: {bar}| {n_fmt}/{total_fmt} [{elapsed}]"
    with tqdm(total=1, desc=description, file=sys.stdout, bar_format=fmt, ncols=80) as step:
        yield
        step.update(1)


def show_line(trainer: Trainer, line: str) -> None:
    """Print ``line`` on a line of its own, above any progress bar (not glued to it)."""
    bar = trainer.progress_bar_callback
    if isinstance(bar, TQDMProgressBar) and bar.is_enabled:
        from tqdm import tqdm

        tqdm.write(line, file=sys.stdout)
    else:
        print(line, flush=True)


class _DataProtocol:
    """A callback's rollout protocol: the named task's, built (and checked) at
    construction, else the data's (:func:`~hnn_pl.evaluation.protocols.data_protocol`)
    at ``setup``; ``protocol`` is ``None`` until then."""

    def _set_protocol(self, task: str | None, name: str, overrides: Any) -> None:
        self._protocol_args = (name, overrides)
        self.protocol = None if task is None else task_protocol(task, name, overrides)

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        super().setup(trainer, pl_module, stage)
        if self.protocol is None:
            self.protocol = data_protocol(trainer.datamodule, *self._protocol_args)


class RolloutCallback(_DataProtocol, Callback):
    """Roll the model out from the held-out starts under a task's protocol and log it.

    Every ``every_n_epochs`` epochs and at the end of ``fit`` (only with a logger:
    nothing is computed that is not recorded), and in ``test``, rank zero:
    :func:`hnn_pl.evaluation.evaluate` on all held-out starts in one batch, logged as
    ``rollout/<metric>`` (``energy_mse`` = ``mean_{t,b} (E(y_true) − E(y_pred))²``,
    ``state_mse``, ``motion_error``, ``valid_time``, ``conserved_drift`` (HNN),
    ``field_error`` (state models: :func:`hnn_pl.evaluation.metrics.field_error`, the relative
    error of ``f_θ`` on the true states); pixel: ``pixel_mse``,
    ``latent_mse``, ``probe_mse``) over the rows that stayed finite, and
    ``rollout/diverged_rows``: a diverging row stops alone and the fit goes on.
    With ``log_images`` and TensorBoard: ``rollout/phase_portrait``,
    ``rollout/energy``, pixel ``rollout/frames``.

    Args:
        task: a name in :data:`hnn_pl.tasks.TASKS`; ``None``: the task of the data
            (:func:`hnn_pl.evaluation.protocols.data_protocol`; a recording's held-out
            trajectories as recorded).
        protocol: ``"clean"``, ``"reference"`` (the state tasks': scipy's procedure)
            or ``"independent"``.
        every_n_epochs: period during training; ``0``: only at the end of fit.
        log_images: draw the figures.
        overrides: protocol fields to change, e.g. ``{method: rk4, step_size: 0.05}``.

    ``metrics`` holds the last rollout's metrics (``{}`` before the first).
    """

    def __init__(
        self,
        task: str | None = None,
        protocol: str = "clean",
        every_n_epochs: int = 100,
        log_images: bool = True,
        overrides: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        if every_n_epochs < 0:
            raise ValueError(f"every_n_epochs must be >= 0, got {every_n_epochs}")
        self._set_protocol(task, protocol, overrides)
        self.every_n_epochs = every_n_epochs
        self.log_images = log_images
        self._last_logged_step = -1
        self.metrics: dict[str, float] = {}

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        """Take the protocol from the data's task if none was named (``task=None``), and
        record what tells runs apart in every logger's hyperparameters: the model's
        class, the system with its parameters, the rollout protocol."""
        super().setup(trainer, pl_module, stage)
        cls = type(pl_module)
        dm_hparams = getattr(trainer.datamodule, "hparams", {})
        run = {
            "model_class": f"{cls.__module__}.{cls.__qualname__}",
            "system": dm_hparams.get("system", type(trainer.datamodule).__name__),
            "rollout_protocol": vars(self.protocol),
        }
        for logger in trainer.loggers:
            logger.log_hyperparams(run)

    def _images(self, trainer: Trainer, r: Rollout) -> None:
        if not (self.log_images and isinstance(trainer.logger, TensorBoardLogger)):
            return
        from hnn_pl import plotting

        writer, step = trainer.logger.experiment, trainer.global_step
        for tag, fig in plotting.figures(r).items():
            writer.add_figure(tag, fig, step)
        if r.has_frames:
            writer.add_figure("rollout/frames", plotting.frames_figure(r), step)

    def _log_during_fit(
        self, trainer: Trainer, pl_module: LightningModule, final: bool = False
    ) -> None:
        if not (trainer.is_global_zero and trainer.loggers):
            return
        if trainer.global_step == self._last_logged_step:
            return
        self._last_logged_step = trainer.global_step
        with shown_as_step(trainer, "Final rollout") if final else nullcontext():
            metrics, r = evaluate(pl_module, trainer.datamodule, self.protocol)
            self.metrics = metrics
            tagged = {f"rollout/{k}": v for k, v in metrics.items()}
            for logger in trainer.loggers:
                logger.log_metrics(tagged, step=trainer.global_step)
            self._images(trainer, r)

    def on_train_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if self.every_n_epochs and (trainer.current_epoch + 1) % self.every_n_epochs == 0:
            self._log_during_fit(trainer, pl_module)

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        self._log_during_fit(trainer, pl_module, final=True)

    def on_test_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        with shown_as_step(trainer, "Rollout"):
            metrics, r = evaluate(pl_module, trainer.datamodule, self.protocol)
        self.metrics = metrics
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


class RolloutWriter(_DataProtocol, BasePredictionWriter):
    """``predict`` that answers: rollouts written to a file beside the run.

    At the end of ``predict`` (rank zero) the model is rolled out under the task's
    protocol from the held-out starts, or from ``starts`` (a ``torch.save``-d
    ``(B, D)`` tensor; pixel: frame pairs), and ``torch.save``-d as a dict:
    held-out: ``t (T,)``, ``y_true``/``y_pred (T, B, D)``, ``energy_true``/
    ``energy_pred (T, B)``, ``h_pred`` (HNN), ``metrics``; pixel also
    ``frames_true``/``frames_pred``, ``z_pred`` (``y`` are the probe's ``(q, p)``); a
    recording (:class:`~hnn_pl.data.RecordingData`) also ``t0 (B,)`` float64, the
    file's time of each row's ``t = 0`` (its times in the file: ``t + t0[b]``).
    Given starts: ``t``, ``y``, ``h``, ``energy`` (state), ``frames`` (pixel), each
    row's ``status`` and ``t_stop`` (rows that stopped early are counted in the printed
    line; the CLI refuses a file of starts that is not a finite ``(B, D)`` tensor). A
    state model's ``starts`` may instead be positions windows (a CSV
    ``trajectory,time,q…`` or a dict ``{"q": (B, M, k), "t": (M,)}``,
    :func:`~hnn_pl.evaluation.observer.read_positions_window`): the observer infers each
    row's start at its first time, and the file also holds ``t0 (B,)`` (that time) and
    ``observed_rms (B,)`` (the observer's position residual). The
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
        task: str | None = None,
        protocol: str = "clean",
        overrides: dict[str, Any] | None = None,
        starts: str | None = None,
        filename: str = "rollouts.pt",
    ) -> None:
        super().__init__(write_interval="epoch")
        warnings.filterwarnings("ignore", message=".*infer the batch indices.*")
        self._set_protocol(task, protocol, overrides)
        self.starts = starts
        self.filename = filename
        self.path: Path | None = None
        self.metrics: dict[str, float] = {}

    def _directory(self, trainer: Trainer) -> Path:
        if trainer.ckpt_path:
            return run_directory(trainer.ckpt_path) or Path(trainer.ckpt_path).parent
        if trainer.logger is not None and trainer.log_dir is not None:
            return Path(trainer.log_dir)
        return Path.cwd()

    def _given_starts(self, pl_module: LightningModule, dm: Any) -> dict[str, Any]:
        """The rollouts from the file's starts, or from the starts the observer infers
        from its positions windows (then also ``t0``, each row's first time in the
        file, and ``observed_rms``, the observer's fit of the window)."""
        from hnn_pl.evaluation.observer import (
            observe,
            read_positions_window,
            training_momentum_bound,
        )
        from hnn_pl.evaluation.views import is_pixel_model

        p, view = self.protocol, view_of(pl_module)
        csv = Path(self.starts).suffix == ".csv"
        y0 = None if csv else torch_load(self.starts)
        extra: dict[str, Any] = {}
        if not torch.is_tensor(y0):
            if is_pixel_model(pl_module):
                raise ValueError(f"starts {self.starts}: a pixel model starts from frames")
            window = read_positions_window(self.starts, view.start_width(dm) // 2)
            bound = training_momentum_bound(pl_module, dm)
            o = observe(pl_module, window.t, window.q, method="rk4", p_bound=bound)
            y0, extra = o.y0, {"t0": window.t0, "observed_rms": o.rms}
        t = view.times(p.t_end, p.n_points)
        out = rollout(pl_module, y0, t, dtype=p.dtype, energy=view.energy(dm), **p.solver_kwargs())
        return {**out.as_dict(), **extra}

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
            with shown_as_step(trainer, "Rollout"):
                metrics, r = evaluate(pl_module, dm, self.protocol)
            self.metrics = metrics
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
            t0 = getattr(dm, "test_t0", None)
            if t0 is not None:
                payload["t0"] = t0[: r.y_true.shape[1]]
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
        show_line(trainer, f"wrote rollouts {shape} (T, B, D) to {self.path}{note}")
