"""The baseline: an MLP that outputs ``dy/dt`` directly."""

from __future__ import annotations

from hnn_pl.models.base import DynamicsModel, angle_inputs
from hnn_pl.nets import MLP, DirectField


class Baseline(DynamicsModel):
    """``dy/dt = MLP(y)`` with ``MLP: 2k → h → h → 2k`` (tanh, no output bias).

    Arguments as :class:`~hnn_pl.models.base.DynamicsModel`.
    """

    def build_field(
        self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> DirectField:
        return DirectField(
            MLP(input_dim, input_dim, hidden_dim, n_hidden, activation, **angle_inputs(self))
        )
