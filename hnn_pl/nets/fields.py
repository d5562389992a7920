"""Vector fields built from networks: the baseline's direct field and the HNN's J∇H."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from hnn_pl.systems.base import symplectic_gradient


class DirectField(nn.Module):
    """The baseline: the network's output *is* ``dy/dt``, ``(batch, 2k) -> (batch, 2k)``."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, y: Tensor) -> Tensor:
        return self.net(y)

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``f(t, y) = net(y)``: the signature ``odeint`` expects."""
        return self.net(y)


class HamiltonianField(nn.Module):
    """An HNN: a scalar ``H_θ(y)`` and its symplectic gradient ``dy/dt = J∇H_θ``.

    ``∇H_θ`` comes in closed form when the network offers ``value_and_input_grad``
    (the tanh :class:`~hnn_pl.nets.MLP`), otherwise from ``torch.autograd.grad``,
    with ``create_graph`` only when the caller records gradients (training). Both
    paths work under ``torch.no_grad`` and ``torch.inference_mode``, so Lightning's
    default ``Trainer(inference_mode=True)`` can validate, test and predict.

    Args:
        net: maps ``(batch, 2k)`` to ``(batch, 1)``; the first output is ``H``.
        closed_form: use the network's closed-form gradient where it has one.
    """

    def __init__(self, net: nn.Module, closed_form: bool = True) -> None:
        super().__init__()
        self.net = net
        self.closed_form = closed_form

    def hamiltonian(self, y: Tensor) -> Tensor:
        """``H_θ(y)``: ``(batch, 2k) -> (batch,)``."""
        return self.net(y)[..., 0]

    def value_and_grad(self, y: Tensor) -> tuple[Tensor, Tensor]:
        """``H_θ(y) (batch,)`` and ``∇H_θ(y) (batch, 2k)``."""
        if self.closed_form and getattr(self.net, "activation", None) == "tanh":
            return self.net.value_and_input_grad(y)
        record = torch.is_grad_enabled() and not torch.is_inference_mode_enabled()
        with torch.inference_mode(False), torch.enable_grad():
            if not y.requires_grad:
                y = y.clone().requires_grad_(True)
            h = self.net(y)[..., 0]
            (grad,) = torch.autograd.grad(h.sum(), y, create_graph=record)
        return (h, grad) if record else (h.detach(), grad.detach())

    def forward(self, y: Tensor) -> Tensor:
        return symplectic_gradient(self.value_and_grad(y)[1])

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``f(t, y) = J∇H_θ(y) = (∂H/∂p, −∂H/∂q)``, ``(batch, 2k) -> (batch, 2k)``."""
        return symplectic_gradient(self.value_and_grad(y)[1])
