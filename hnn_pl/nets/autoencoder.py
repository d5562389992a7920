"""The pixel pendulum's MLP autoencoder, split into an encoder and a decoder.

As the reference (``MLPAutoencoder`` in ``nn_models.py`` of greydanus/hamiltonian-nn,
``experiment-pixels`` arguments 1568 → 200 → 2, ReLU): each half is four linear layers
with residual connections ``h + σ(W h + b)`` around the middle two, a linear latent
and a linear output (**no sigmoid**), every weight orthogonally initialised (gain 1),
biases at PyTorch's default. The layers keep the reference's names (``linear1``–
``linear4``, ``linear5``–``linear8``), so a reference state dict splits by key.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from hnn_pl.nets.mlp import activation_fn

_ACTIVATIONS = {"relu": torch.relu, "tanh": torch.tanh}


class _ResidualMLP(nn.Module):
    """``(..., in_dim) -> (..., out_dim)``: ``h₁ = σ(W₁a + b₁)``, ``h₂ = h₁ + σ(W₂h₁ + b₂)``,
    ``h₃ = h₂ + σ(W₃h₂ + b₃)``, out ``= W₄h₃ + b₄``; layers ``linear{first}`` … ``+3``."""

    first = 1

    def __init__(self, in_dim: int, hidden_dim: int, out_dim: int, activation: str) -> None:
        super().__init__()
        self._act = activation_fn(activation, _ACTIVATIONS)
        self.activation = activation
        dims = (in_dim, hidden_dim, hidden_dim, hidden_dim, out_dim)
        layers = [nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:])]
        for i, layer in enumerate(layers):
            nn.init.orthogonal_(layer.weight)
            setattr(self, f"linear{self.first + i}", layer)

    def forward(self, x: Tensor) -> Tensor:
        first, second, third, last = (getattr(self, f"linear{self.first + i}") for i in range(4))
        h = self._act(first(x))
        h = h + self._act(second(h))
        h = h + self._act(third(h))
        return last(h)


class PixelEncoder(_ResidualMLP):
    """``x (..., input_dim) -> z (..., latent_dim)``, layers ``linear1``–``linear4``:
    1568 → 200 → 200 → 200 → 2 by default (two 28 × 28 frames, flattened row-major
    and concatenated, in; ``(q, p)``-like latent out).

    Args:
        input_dim: length of the flattened input (``2·28² = 1568``).
        hidden_dim: width of the three hidden layers.
        latent_dim: length of the latent code.
        activation: ``"relu"`` (reference, pixel task) or ``"tanh"``.
    """

    def __init__(
        self,
        input_dim: int = 1568,
        hidden_dim: int = 200,
        latent_dim: int = 2,
        activation: str = "relu",
    ) -> None:
        super().__init__(input_dim, hidden_dim, latent_dim, activation)


class PixelDecoder(_ResidualMLP):
    """``z (..., latent_dim) -> x̂ (..., output_dim)``, the encoder's mirror image
    (layers ``linear5``–``linear8``, linear output). Arguments as :class:`PixelEncoder`."""

    first = 5

    def __init__(
        self,
        latent_dim: int = 2,
        hidden_dim: int = 200,
        output_dim: int = 1568,
        activation: str = "relu",
    ) -> None:
        super().__init__(latent_dim, hidden_dim, output_dim, activation)
