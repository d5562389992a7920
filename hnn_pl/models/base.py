"""What the state-space models share: loss, logging, optimiser, rollouts."""

from __future__ import annotations

from torch import Tensor, nn
from torchmetrics import MeanSquaredError

from hnn_pl.models.recipe import RecipeModel


class DynamicsModel(RecipeModel):
    """A LightningModule that learns ``dy/dt = f_θ(y)`` from ``(y, dy/dt)`` pairs.

    Subclasses implement :meth:`build_field`; ``field`` (public) is the plain module it
    returns, with ``vector_field(t, y)`` (and ``hamiltonian(y)`` for an HNN): what
    rollouts integrate. Batches are ``(y, dydt)``, both ``(batch, 2k)``; the loss is
    ``mean((f_θ(y) − dy/dt)²)``. Logs ``train/loss`` every step and ``val/loss``,
    ``test/loss`` as the MSE over the whole split (torchmetrics).

    Args:
        input_dim: ``2k``, the state size (linked from the DataModule by the CLI).
        hidden_dim: ``h``, the MLP's width (200 in the paper).
        n_hidden: number of hidden layers (2).
        activation: hidden nonlinearity (``"tanh"``).
        lr, weight_decay, optimizer, schedule, warmup_steps, inner_steps, grad_clip,
            on_nonfinite: the training recipe (:class:`~hnn_pl.models.recipe.RecipeModel`;
            the paper's: Adam, constant rate).
    """

    def __init__(
        self,
        input_dim: int = 2,
        hidden_dim: int = 200,
        n_hidden: int = 2,
        activation: str = "tanh",
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        optimizer: str = "adam",
        schedule: str = "constant",
        warmup_steps: int = 0,
        inner_steps: int = 1,
        grad_clip: float | None = None,
        on_nonfinite: str = "stop",
    ) -> None:
        recipe = (lr, weight_decay, optimizer, schedule, warmup_steps, inner_steps, grad_clip)
        super().__init__(*recipe, on_nonfinite)
        if input_dim < 2 or input_dim % 2 or hidden_dim < 1 or n_hidden < 1:
            raise ValueError(
                "input_dim must be even and >= 2 (y = (q, p)), hidden_dim and n_hidden >= 1; "
                f"got input_dim={input_dim}, hidden_dim={hidden_dim}, n_hidden={n_hidden}"
            )
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
        """``f_θ(t, y)``: ``(batch, 2k) -> (batch, 2k)``, for ``odeint`` or scipy; ``y``
        of any float dtype (evaluated in the model's, returned in ``y``'s)."""
        return self.in_own_dtype(lambda y: self.field.vector_field(t, y), y)

    def forward(self, y: Tensor) -> Tensor:
        return self.field.vector_field(None, y)

    def rollout(self, y0: Tensor, t: Tensor, method: str = "dopri5", **kwargs) -> Tensor:
        """Integrate the learned field in the model's dtype: ``y0 (batch, 2k)``, ``t (T,)``
        -> ``(T, batch, 2k)``; ``kwargs`` go to :func:`hnn_pl.odeint`. For energies and
        ``H_θ`` as well, use :func:`hnn_pl.rollout`."""
        from hnn_pl.rollouts import rollout

        return rollout(self, y0, t, method=method, dtype="model", **kwargs).y

    def training_loss(self, batch: tuple[Tensor, Tensor]) -> dict[str, Tensor]:
        y, dydt = batch
        return {"loss": nn.functional.mse_loss(self(y), dydt)}

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
