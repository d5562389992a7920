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


def scalar_value_and_grad(
    net: nn.Module, y: Tensor, closed_form: bool = True
) -> tuple[Tensor, Tensor]:
    """A scalar network's value ``s(y) (batch,)`` (its first output) and ``∇s(y) (batch, 2k)``.

    Closed-form for the tanh :class:`~hnn_pl.nets.MLP` when ``closed_form``; otherwise
    ``torch.autograd.grad``, with ``create_graph`` only when the caller records
    gradients (training). Works under ``torch.no_grad`` and ``torch.inference_mode``.
    """
    if closed_form and getattr(net, "activation", None) == "tanh":
        return net.value_and_input_grad(y)
    record = torch.is_grad_enabled() and not torch.is_inference_mode_enabled()
    with torch.inference_mode(False), torch.enable_grad():
        if not y.requires_grad:
            y = y.clone().requires_grad_(True)
        s = net(y)[..., 0]
        (grad,) = torch.autograd.grad(s.sum(), y, create_graph=record)
    return (s, grad) if record else (s.detach(), grad.detach())


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
        return scalar_value_and_grad(self.net, y, self.closed_form)

    def forward(self, y: Tensor) -> Tensor:
        return symplectic_gradient(self.value_and_grad(y)[1])

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``f(t, y) = J∇H_θ(y) = (∂H/∂p, −∂H/∂q)``, ``(batch, 2k) -> (batch, 2k)``."""
        return symplectic_gradient(self.value_and_grad(y)[1])


class DissipativeField(HamiltonianField):
    """A dissipative HNN (Sosanya & Greydanus 2022): ``dy/dt = J∇H_θ(y) + M∇D_φ(y)``.

    An HNN's ``H_θ`` (:class:`HamiltonianField`: ``hamiltonian``, ``value_and_grad``)
    plus a second scalar network ``D_φ``, a dissipation potential (Helmholtz's
    irrotational part). ``M`` is the identity (``momentum_only=False``: the paper's
    Helmholtz form) or the projection on the momenta (``True``: Rayleigh's form,
    friction forces ``dp/dt ∋ ∂D_φ/∂p`` and ``dq/dt = ∂H_θ/∂p`` untouched). Along the
    field ``dH_θ/dt = ∇H_θ · M∇D_φ``: zero only where the learned dissipation vanishes,
    so ``H_θ`` decays on data with friction.

    Args:
        h_net, d_net: each maps ``(batch, 2k)`` to ``(batch, 1)``.
        momentum_only: Rayleigh's form (``True``) or the full gradient.
        closed_form: use the networks' closed-form gradients where they have one.
    """

    def __init__(
        self,
        h_net: nn.Module,
        d_net: nn.Module,
        momentum_only: bool = True,
        closed_form: bool = True,
    ) -> None:
        super().__init__(h_net, closed_form)
        self.d_net = d_net
        self.momentum_only = momentum_only

    def dissipation(self, y: Tensor) -> Tensor:
        """``D_φ(y)``: ``(batch, 2k) -> (batch,)``."""
        return self.d_net(y)[..., 0]

    def dissipative_part(self, y: Tensor) -> Tensor:
        """``M∇D_φ(y)``: ``(batch, 2k) -> (batch, 2k)``."""
        grad = scalar_value_and_grad(self.d_net, y, self.closed_form)[1]
        if self.momentum_only:
            k = grad.shape[-1] // 2
            grad = torch.cat([torch.zeros_like(grad[..., :k]), grad[..., k:]], dim=-1)
        return grad

    def forward(self, y: Tensor) -> Tensor:
        return self.vector_field(None, y)

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``f(t, y) = J∇H_θ(y) + M∇D_φ(y)``, ``(batch, 2k) -> (batch, 2k)``."""
        return super().vector_field(t, y) + self.dissipative_part(y)
