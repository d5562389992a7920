"""The rollout callback: long ODE rollouts of the learned field, logged to TensorBoard."""

from __future__ import annotations

import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.loggers import TensorBoardLogger

from hnn_pl import rollout as R

#: at most this many training inputs estimate the spread of ``H_θ``
_SCALE_ROWS = 4096


class RolloutCallback(Callback):
    """Integrate the model from the held-out trajectories' starts and score it.

    Every ``every_n_epochs`` training epochs, at the end of ``fit`` and in ``test``
    (rank zero only), all held-out starts are integrated in one batch with
    :func:`hnn_pl.odeint` and compared with the truth the DataModule provides
    (:meth:`~hnn_pl.data.base.TrajectoryDataModule.rollout_target`). Logged:

    - ``rollout/energy_mse``: ``mean_{t,b} (E(y_true) − E(y_pred))²``, ``E`` the
      system's energy;
    - ``rollout/state_mse``: ``mean_{t,b,d} (y_true − y_pred)²``;
    - ``rollout/conserved_drift`` (models with ``hamiltonian``):
      ``mean_b max_t |H_θ(y_t) − H_θ(y_0)| / (|H_θ(y_0)| + scale)`` with ``scale``
      the standard deviation of ``H_θ`` over (up to 4096) training inputs;
    - images ``rollout/phase_portrait`` and ``rollout/energy`` (energy and ``H_θ``
      over time), when ``log_images`` and the logger is TensorBoard.

    Args:
        every_n_epochs: period during training; ``0`` only at the end of fit.
        t_end: horizon; ``None`` uses the held-out trajectories' own times.
        n_points: output times on ``[t₀, t_end]``.
        method: integrator (see :data:`hnn_pl.integrate.METHODS`).
        rtol, atol: tolerances of adaptive methods (and implicit iterations).
        step_size: step of fixed-step methods (``None``: one step per output).
        dtype: ``"float64"`` (default) integrates a float64 copy of the field, so
            the integrator's own error stays far below the model's; ``"model"``
            integrates in the model's dtype.
        max_trajectories: use only the first this many starts (``None``: all).
        log_images: draw the figures.
    """

    def __init__(
        self,
        every_n_epochs: int = 100,
        t_end: float | None = 20.0,
        n_points: int = 200,
        method: str = "dopri5",
        rtol: float = 1e-9,
        atol: float = 1e-9,
        step_size: float | None = None,
        dtype: str = "float64",
        max_trajectories: int | None = None,
        log_images: bool = True,
    ) -> None:
        super().__init__()
        self.every_n_epochs = every_n_epochs
        self.t_end = t_end
        self.n_points = n_points
        self.method = method
        self.solver_kwargs = {"rtol": rtol, "atol": atol, "step_size": step_size}
        self.dtype = None if dtype == "model" else getattr(torch, dtype)
        self.max_trajectories = max_trajectories
        self.log_images = log_images
        self._last_logged_step = -1

    def run(self, trainer: Trainer, pl_module: LightningModule) -> tuple[dict, R.Rollout]:
        """Roll out and compute the metrics; returns ``({tag: value}, rollout)``."""
        dm = trainer.datamodule
        t, y_true = dm.rollout_target(self.t_end, self.n_points)
        if self.max_trajectories is not None:
            y_true = y_true[:, : self.max_trajectories]
        y_true = y_true.to(pl_module.device)
        was_training = pl_module.training
        pl_module.eval()
        try:
            r = R.rollout(
                pl_module.field,
                t.to(pl_module.device),
                y_true,
                dm.energy,
                method=self.method,
                dtype=self.dtype,
                scale_inputs=dm.x_train[:_SCALE_ROWS].to(pl_module.device),
                **self.solver_kwargs,
            )
            metrics = {
                "rollout/energy_mse": R.energy_mse(r),
                "rollout/state_mse": R.state_mse(r),
            }
            if r.h_pred is not None:
                metrics["rollout/conserved_drift"] = R.conserved_drift(r)
        finally:
            pl_module.train(was_training)
        return {k: float(v) for k, v in metrics.items()}, r

    def _images(self, trainer: Trainer, r: R.Rollout) -> None:
        if not (self.log_images and isinstance(trainer.logger, TensorBoardLogger)):
            return
        from hnn_pl import plotting

        writer = trainer.logger.experiment
        step = trainer.global_step
        writer.add_figure("rollout/phase_portrait", plotting.phase_portrait(r), step)
        writer.add_figure("rollout/energy", plotting.energy_over_time(r), step)

    def _log_during_fit(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if not trainer.is_global_zero or trainer.global_step == self._last_logged_step:
            return
        self._last_logged_step = trainer.global_step
        metrics, r = self.run(trainer, pl_module)
        for logger in trainer.loggers:
            logger.log_metrics(metrics, step=trainer.global_step)
        self._images(trainer, r)

    def on_train_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if self.every_n_epochs and (trainer.current_epoch + 1) % self.every_n_epochs == 0:
            self._log_during_fit(trainer, pl_module)

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        self._log_during_fit(trainer, pl_module)

    def on_test_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        metrics, r = self.run(trainer, pl_module)
        for tag, value in metrics.items():
            pl_module.log(tag, value, rank_zero_only=True)
        self._images(trainer, r)
