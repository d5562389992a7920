"""The multilayer perceptron of the paper, with a closed-form input gradient."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

_ACTIVATIONS = {"tanh": torch.tanh, "relu": torch.relu, "softplus": nn.functional.softplus}


def activation_fn(name: str, table: dict[str, Callable] = _ACTIVATIONS) -> Callable:
    """``table[name]``, or a ValueError listing the valid names."""
    if name not in table:
        raise ValueError(f"activation must be one of {sorted(table)}, got {name!r}")
    return table[name]


class MLP(nn.Module):
    """``Linear(d→h) → σ → Linear(h→h) → σ → … → Linear(h→out, no bias)``.

    The reference architecture: orthogonal initialisation of every weight matrix,
    PyTorch's default biases, no bias on the output layer.

    Args:
        input_dim: ``d``, the length of the input's last axis.
        output_dim: ``out``.
        hidden_dim: ``h``, the width of each hidden layer.
        n_hidden: number of hidden layers (2 in the paper).
        activation: ``"tanh"`` (paper), ``"relu"`` or ``"softplus"``.
    """

    def __init__(
        self,
        input_dim: int,
        output_dim: int,
        hidden_dim: int = 200,
        n_hidden: int = 2,
        activation: str = "tanh",
    ) -> None:
        super().__init__()
        self._act = activation_fn(activation)
        dims = [input_dim] + [hidden_dim] * n_hidden
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.out = nn.Linear(hidden_dim, output_dim, bias=False)
        self.activation = activation
        for layer in [*self.hidden, self.out]:
            nn.init.orthogonal_(layer.weight)

    def forward(self, x: Tensor) -> Tensor:
        """``(..., d) -> (..., out)``."""
        for layer in self.hidden:
            x = self._act(layer(x))
        return self.out(x)

    def value_and_input_grad(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``f(x)`` and ``∇ₓ f(x)`` of the first output, in closed form for ``tanh``.

        With ``hₗ = tanh(Wₗ hₗ₋₁ + bₗ)``, ``h₀ = x`` and ``f = w·h_L``:
        ``∇ₓ f = W₁ᵀ[(1 − h₁²) ⊙ W₂ᵀ[(1 − h₂²) ⊙ … w]]``, a few matrix products and
        no autograd graph of a graph, so a training loss on ``∇f`` needs only one
        ordinary backward pass, and the gradient is available under
        ``torch.inference_mode``. ``x (batch, d)`` -> ``f (batch,)``, ``∇ₓ f (batch, d)``;
        NotImplementedError for activations other than ``tanh``.
        """
        if self.activation != "tanh":
            raise NotImplementedError("closed-form input gradient is implemented for tanh only")
        hs = []
        h = x
        for layer in self.hidden:
            h = torch.tanh(layer(h))
            hs.append(h)
        w = self.out.weight[0]
        value = h @ w
        g = (1 - hs[-1] ** 2) * w
        for layer, h_prev in zip(reversed(self.hidden[1:]), reversed(hs[:-1])):
            g = (g @ layer.weight) * (1 - h_prev**2)
        return value, g @ self.hidden[0].weight

    def activations(self, x: Tensor) -> list[Tensor]:
        """The hidden layers' outputs ``[h₁, …, h_L]``, each ``(B, h)``: what
        :meth:`input_vjp` and :meth:`input_jvp` reuse (``tanh`` only)."""
        if self.activation != "tanh":
            raise NotImplementedError("closed-form input derivatives are implemented for tanh only")
        hs, h = [], x
        for layer in self.hidden:
            h = torch.tanh(layer(h))
            hs.append(h)
        return hs

    def input_vjp(self, hs: list[Tensor], cotangent: Tensor) -> Tensor:
        """``(∂f/∂x)ᵀ c`` at the input whose :meth:`activations` are ``hs``, in closed form
        (``tanh``): ``c (B, out) -> (B, d)``."""
        g = cotangent @ self.out.weight
        for i in range(len(self.hidden) - 1, -1, -1):
            g = (g * (1 - hs[i] ** 2)) @ self.hidden[i].weight
        return g

    def input_jvp(self, hs: list[Tensor], tangent: Tensor) -> Tensor:
        """``(∂f/∂x) u`` at the input whose :meth:`activations` are ``hs``, in closed form
        (``tanh``): ``u (B, d) -> (B, out)``."""
        t = tangent
        for layer, h in zip(self.hidden, hs):
            t = (t @ layer.weight.T) * (1 - h**2)
        return t @ self.out.weight.T
