"""The rollout callback: long ODE rollouts of the learned field, logged to TensorBoard."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.loggers import TensorBoardLogger
from torch import Tensor

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


# --------------------------------------------------------------------------- pixel pendulum


@dataclass
class PixelRollout(R.Rollout):
    """A latent rollout of a pixel model, decoded and probed.

    The inherited fields hold the *probe's* view, so the state-task plots and
    metrics apply: ``t (T,)`` physical times ``k·dt``; ``y_true (T, B, 2)`` the
    true ``(q, p) = (θ, c·θ̇)``; ``y_pred`` the linear probe of the integrated
    latents; ``e_true, e_pred (T, B)`` the energy ``α(1 − cos q) + p²`` of each;
    ``h_pred (T, B)`` the learned ``H_θ`` along the latent rollout (HNN only) and
    ``h_scale`` its standard deviation over the encoded training inputs.

    Attributes:
        z_true: ``(T, B, L)`` the encodings of the true frame pairs.
        z_pred: ``(T, B, L)`` the integrated latents, from ``z_true[0]``.
        x_true: ``(T, B, D)`` the true frame pairs.
        x_pred: ``(T, B, D)`` the decoded ``z_pred``.
        probe: ``(L + 1, 2)`` least-squares weights, ``(q, p) ≈ [z, 1] @ probe``.
        probe_mse: the probe's mean squared residual on the training inputs.
    """

    z_true: Tensor | None = None
    z_pred: Tensor | None = None
    x_true: Tensor | None = None
    x_pred: Tensor | None = None
    probe: Tensor | None = None
    probe_mse: Tensor | float = 0.0


def fit_probe(z: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """Affine least squares ``target ≈ [z, 1] @ W`` in float64.

    Args:
        z: ``(N, L)`` latents.
        target: ``(N, K)``.

    Returns:
        ``W (L + 1, K)`` and the mean squared residual.
    """
    a = torch.cat([z.double(), z.new_ones(len(z), 1, dtype=torch.float64)], -1)
    w = torch.linalg.lstsq(a, target.double()).solution
    return w, ((a @ w - target.double()) ** 2).mean()


def apply_probe(w: Tensor, z: Tensor) -> Tensor:
    """``[z, 1] @ W``: ``(..., L) -> (..., K)`` in float64."""
    return z.double() @ w[:-1] + w[-1]


class PixelRolloutCallback(RolloutCallback):
    """Latent rollouts of a pixel model (:class:`~hnn_pl.models.AutoencoderHNN` or
    :class:`~hnn_pl.models.AutoencoderBaseline`) on
    :class:`~hnn_pl.data.pixel.PixelPendulumData`, scored in pixels and energy.

    Scheduled as :class:`RolloutCallback` (every ``every_n_epochs`` training epochs,
    at the end of ``fit``, in ``test``; rank zero only; during ``fit`` only when the
    trainer has a logger). Each evaluation:

    1. encodes up to ``probe_rows`` training inputs and fits the linear probe
       ``z ↦ (θ, c·θ̇)`` by least squares (affine, float64) on their true states;
    2. encodes the first frame pair of every held-out trajectory and integrates the
       latent field over ``n_frames`` frames (``t = k·frame_dt`` in the model's
       time unit, ``k = 0 … n_frames − 1``; a float64 copy of the field by default);
    3. decodes the latents and probes them.

    Logged: ``rollout/energy_mse`` ``mean_{t,b} (E(y_true) − E(probe(z)))²`` with
    ``E = α(1 − cos q) + p²`` (α = 1.875 by default, the DataModule's
    ``energy_coef``); ``rollout/state_mse`` (probe vs true ``(q, p)``);
    ``rollout/pixel_mse`` (decoded vs true frame pairs); ``rollout/latent_mse``
    (integrated vs encoded true pairs); ``rollout/probe_mse`` (the probe's residual
    on the training set, how linear the encoding is); for an HNN
    ``rollout/conserved_drift`` as :func:`hnn_pl.rollout.conserved_drift`, the
    scale being the std of ``H_θ`` over the encoded training inputs. Images (with a
    TensorBoard logger and ``log_images``): ``rollout/frames`` (true frames above
    decoded ones, first trajectory, ``n_strip`` frames evenly spaced; the second
    frame of each pair), ``rollout/phase_portrait`` (the latent plane: encoded
    truth solid, rollout dashed) and ``rollout/energy`` (energy over time, and
    ``H_θ``).

    Each model is evaluated with its own encoder and its own probe (the reference's
    early evaluation encoded with the HNN's encoder even for the baseline).

    Args:
        every_n_epochs: period during training; ``0`` only at the end of fit.
        n_frames: rollout length in frames (200).
        method, rtol, atol, step_size, dtype, max_trajectories, log_images: as
            :class:`RolloutCallback`.
        probe_rows: training inputs the probe and the ``H_θ`` scale use (``None``:
            all).
        n_strip: frames per row of ``rollout/frames``.
    """

    def __init__(
        self,
        every_n_epochs: int = 25,
        n_frames: int = 200,
        method: str = "dopri5",
        rtol: float = 1e-9,
        atol: float = 1e-9,
        step_size: float | None = None,
        dtype: str = "float64",
        max_trajectories: int | None = None,
        log_images: bool = True,
        probe_rows: int | None = None,
        n_strip: int = 10,
    ) -> None:
        super().__init__(
            every_n_epochs=every_n_epochs,
            t_end=None,
            n_points=n_frames,
            method=method,
            rtol=rtol,
            atol=atol,
            step_size=step_size,
            dtype=dtype,
            max_trajectories=max_trajectories,
            log_images=log_images,
        )
        self.n_frames = n_frames
        self.probe_rows = probe_rows
        self.n_strip = n_strip

    def run(self, trainer: Trainer, pl_module: LightningModule) -> tuple[dict, PixelRollout]:
        """Probe, roll out, decode and score; returns ``({tag: value}, rollout)``."""
        dm = trainer.datamodule
        device = pl_module.device
        t, y_true, x_true = dm.rollout_truth(n_points=self.n_frames)
        if self.max_trajectories is not None:
            y_true, x_true = y_true[:, : self.max_trajectories], x_true[:, : self.max_trajectories]
        rows = slice(None) if self.probe_rows is None else slice(self.probe_rows)
        was_training = pl_module.training
        pl_module.eval()
        try:
            with torch.no_grad():
                z_train = pl_module.encode(dm.x_train[rows].to(device))
                probe, probe_mse = fit_probe(z_train, dm.canonical(dm.y_train[rows]).to(device))
                x_true = x_true.to(device)
                z_true = pl_module.encode(x_true)
                frame_dt = float(pl_module.hparams.get("frame_dt", 1.0))
                t_model = torch.arange(len(t), dtype=torch.float64, device=device) * frame_dt
                z_pred, field = R.integrate_field(
                    pl_module.field,
                    z_true[0],
                    t_model,
                    method=self.method,
                    dtype=self.dtype,
                    **self.solver_kwargs,
                )
                x_pred = pl_module.decode(z_pred.to(z_true.dtype))
                q_true = dm.canonical(y_true.to(device)).double()
                q_pred = apply_probe(probe, z_pred)
                r = PixelRollout(
                    t=t.double().cpu(),
                    y_true=q_true,
                    y_pred=q_pred,
                    e_true=dm.system.energy(q_true),
                    e_pred=dm.system.energy(q_pred),
                    z_true=z_true.to(z_pred.dtype),
                    z_pred=z_pred,
                    x_true=x_true,
                    x_pred=x_pred,
                    probe=probe,
                    probe_mse=probe_mse,
                )
                metrics = {
                    "rollout/energy_mse": R.energy_mse(r),
                    "rollout/state_mse": R.state_mse(r),
                    "rollout/pixel_mse": ((x_pred - x_true) ** 2).mean(),
                    "rollout/latent_mse": ((z_pred - r.z_true) ** 2).mean(),
                    "rollout/probe_mse": probe_mse,
                }
                if hasattr(field, "hamiltonian"):
                    r.h_pred = field.hamiltonian(z_pred.flatten(0, 1)).reshape(z_pred.shape[:2])
                    r.h_scale = field.hamiltonian(z_train.to(z_pred.dtype)).std()
                    metrics["rollout/conserved_drift"] = R.conserved_drift(r)
        finally:
            pl_module.train(was_training)
        return {k: float(v) for k, v in metrics.items()}, r

    def frames_image(self, r: PixelRollout, trajectory: int = 0) -> Tensor:
        """True (top) and decoded (bottom) frames of one rollout: ``(1, H, W)`` uint8.

        ``n_strip`` frames evenly spaced over the rollout, the second frame of each
        pair, mapped from ``[0, max of the true frames]`` to ``[0, 255]``.
        """
        from hnn_pl.render import frame_strip

        n = r.x_true.shape[0]
        side = int(round((r.x_true.shape[-1] // 2) ** 0.5))
        idx = torch.linspace(0, n - 1, min(self.n_strip, n)).round().long()

        def second(x: Tensor) -> Tensor:
            return x[idx, trajectory, side * side :].reshape(-1, side, side).float().cpu()

        true, pred = second(r.x_true), second(r.x_pred)
        vmax = float(true.max()) or 1.0
        top, bottom = frame_strip(true, vmax=vmax), frame_strip(pred, vmax=vmax)
        gap = torch.full((2, top.shape[1]), 128, dtype=torch.uint8)
        return torch.cat([top, gap, bottom])[None]

    def _images(self, trainer: Trainer, r: PixelRollout) -> None:
        if not (self.log_images and isinstance(trainer.logger, TensorBoardLogger)):
            return
        from hnn_pl import plotting

        writer = trainer.logger.experiment
        step = trainer.global_step
        writer.add_image("rollout/frames", self.frames_image(r), step, dataformats="CHW")
        latent = R.Rollout(r.t, r.z_true, r.z_pred, r.e_true, r.e_pred)
        fig = plotting.phase_portrait(latent)
        ax = fig.axes[0]
        ax.set(xlabel="z_q", ylabel="z_p", title="latent: encoded truth (solid), rollout (dashed)")
        writer.add_figure("rollout/phase_portrait", fig, step)
        writer.add_figure("rollout/energy", plotting.energy_over_time(r), step)

    def _log_during_fit(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.loggers:  # nothing would record the evaluation
            super()._log_during_fit(trainer, pl_module)
