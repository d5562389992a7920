"""The Hamiltonian Neural Network: an MLP for ``H_θ`` and the field ``J∇H_θ``."""

from __future__ import annotations

from torch import Tensor

from hnn_pl.models.base import DynamicsModel, angle_inputs
from hnn_pl.nets import MLP, HamiltonianField


class HNN(DynamicsModel):
    """``dy/dt = J∇H_θ(y) = (∂H_θ/∂p, −∂H_θ/∂q)``, ``H_θ = MLP(y): 2k → h → h → 1``.

    For the tanh MLP ``∇H_θ`` is closed-form: one ordinary backward pass in training,
    evaluation under ``torch.inference_mode``; other activations use autograd.
    Arguments as :class:`~hnn_pl.models.base.DynamicsModel`.
    """

    def build_field(
        self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> HamiltonianField:
        return HamiltonianField(
            MLP(input_dim, 1, hidden_dim, n_hidden, activation, **angle_inputs(self))
        )

    def hamiltonian(self, y: Tensor) -> Tensor:
        """The learned ``H_θ(y)``: ``(batch, 2k) -> (batch,)``."""
        return self.field.hamiltonian(y)
