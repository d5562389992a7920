"""The dissipative HNN: a learned ``H_θ`` plus a learned dissipation ``D_φ``."""

from __future__ import annotations

from torch import Tensor

from hnn_pl.models.base import DynamicsModel
from hnn_pl.nets import MLP, DissipativeField


class DissipativeHNN(DynamicsModel):
    """``dy/dt = J∇H_θ(y) + M∇D_φ(y)`` (Sosanya & Greydanus 2022), for data with friction.

    ``H_θ, D_φ = MLP(y): 2k → h → h → 1`` each; ``M`` projects on the momenta
    (``momentum_only``, Rayleigh's form: friction acts on ``dp/dt`` only) or is the
    identity (the paper's Helmholtz form). The objectives are the
    HNN's; rollouts report ``H_θ``, which decays where ``D_φ`` dissipates.

    Args:
        momentum_only: Rayleigh's form (default) or the full ``∇D_φ``.
        **kwargs: the arguments of :class:`~hnn_pl.models.base.DynamicsModel`.
    """

    def __init__(self, momentum_only: bool = True, **kwargs) -> None:
        self.momentum_only = momentum_only
        super().__init__(**kwargs)

    def build_field(
        self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> DissipativeField:
        return DissipativeField(
            MLP(input_dim, 1, hidden_dim, n_hidden, activation),
            MLP(input_dim, 1, hidden_dim, n_hidden, activation),
            momentum_only=self.momentum_only,
        )

    def hamiltonian(self, y: Tensor) -> Tensor:
        """The learned conservative part ``H_θ(y)``: ``(batch, 2k) -> (batch,)``."""
        return self.field.hamiltonian(y)

    def dissipation(self, y: Tensor) -> Tensor:
        """The learned dissipation potential ``D_φ(y)``: ``(batch, 2k) -> (batch,)``."""
        return self.field.dissipation(y)
