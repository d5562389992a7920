"""What the state-space models share: loss, logging, optimiser, rollouts."""

from __future__ import annotations

import lightning as L
import torch
from torch import Tensor, nn
from torchmetrics import MeanSquaredError

from hnn_pl.integrate import odeint


class DynamicsModel(L.LightningModule):
    """A LightningModule that learns ``dy/dt = f_θ(y)`` from ``(y, dy/dt)`` pairs.

    Subclasses implement :meth:`build_field`, returning a plain module with
    ``vector_field(t, y)``, built on the paper's MLP. Loss:
    ``mean((f_θ(y) − dy/dt)²)`` over batch and dimensions; Adam.

    Batches are ``(y, dydt)``, both ``(batch, 2k)``. Logs ``train/loss`` every step
    and ``val/loss``, ``test/loss`` as the MSE over the whole split (torchmetrics).

    Args:
        input_dim: ``2k``, the state size (linked from the DataModule by the CLI).
        hidden_dim: ``h``, the MLP's width (200 in the paper).
        n_hidden: number of hidden layers (2).
        activation: hidden nonlinearity (``"tanh"``).
        lr: Adam learning rate (1e-3).
        weight_decay: Adam weight decay (task-dependent, see the configs).
    """

    def __init__(
        self,
        input_dim: int = 2,
        hidden_dim: int = 200,
        n_hidden: int = 2,
        activation: str = "tanh",
        lr: float = 1e-3,
        weight_decay: float = 0.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.field = self.build_field(input_dim, hidden_dim, n_hidden, activation)
        self.val_mse = MeanSquaredError()
        self.test_mse = MeanSquaredError()

    def build_field(
        self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> nn.Module:
        """The plain module holding the parameters, with ``vector_field(t, y)``."""
        raise NotImplementedError

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``f_θ(t, y)``: ``(batch, 2k) -> (batch, 2k)``, for ``odeint`` or scipy."""
        return self.field.vector_field(t, y)

    def forward(self, y: Tensor) -> Tensor:
        return self.field.vector_field(None, y)

    def rollout(self, y0: Tensor, t: Tensor, method: str = "dopri5", **kwargs) -> Tensor:
        """Integrate the learned field: ``y0 (batch, 2k)``, ``t (T,)`` -> ``(T, batch, 2k)``.

        Runs without recording gradients; ``kwargs`` go to :func:`hnn_pl.odeint`.
        """
        with torch.no_grad():
            return odeint(self.field.vector_field, y0, t, method=method, **kwargs)

    def training_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> Tensor:
        y, dydt = batch
        loss = nn.functional.mse_loss(self(y), dydt)
        self.log("train/loss", loss, prog_bar=True)
        return loss

    def validation_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> None:
        y, dydt = batch
        self.val_mse(self(y), dydt)
        self.log("val/loss", self.val_mse, prog_bar=True)

    def test_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> None:
        y, dydt = batch
        self.test_mse(self(y), dydt)
        self.log("test/loss", self.test_mse)

    def predict_step(self, batch: tuple[Tensor, ...], batch_idx: int) -> Tensor:
        """The predicted ``dy/dt`` of the batch's states, ``(batch, 2k)``."""
        return self(batch[0])

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(
            self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay
        )
