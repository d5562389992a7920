"""The pixel pendulum's MLP autoencoder, split into an encoder and a decoder.

The reference (``nn_models.py`` of greydanus/hamiltonian-nn, class
``MLPAutoencoder``, built in ``experiment-pixels/train.py`` as
``MLPAutoencoder(args.input_dim, args.hidden_dim, args.latent_dim,
nonlinearity='relu')`` with ``input_dim = 2*28**2``, ``hidden_dim = 200``,
``latent_dim = 2``)::

    for l in [self.linear1, ..., self.linear8]:
      torch.nn.init.orthogonal_(l.weight)  # use a principled initialization

    def encode(self, x):
      h = self.nonlinearity( self.linear1(x) )
      h = h + self.nonlinearity( self.linear2(h) )
      h = h + self.nonlinearity( self.linear3(h) )
      return self.linear4(h)

    def decode(self, z):
      h = self.nonlinearity( self.linear5(z) )
      h = h + self.nonlinearity( self.linear6(h) )
      h = h + self.nonlinearity( self.linear7(h) )
      return self.linear8(h)

So: ReLU, residual connections ``h + σ(W h + b)`` around the two middle layers of each
half, a linear latent and a linear output (**no sigmoid**), every layer with a bias,
every weight orthogonally initialised (gain 1) and the biases left at PyTorch's
default. The layers keep the reference's names (``linear1``–``linear4`` in the
encoder, ``linear5``–``linear8`` in the decoder), so a reference ``MLPAutoencoder``
state dict splits into the two by key.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

_ACTIVATIONS = {"relu": torch.relu, "tanh": torch.tanh}


def _check(activation: str):
    if activation not in _ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {activation!r}")
    return _ACTIVATIONS[activation]


class PixelEncoder(nn.Module):
    """``x (..., input_dim) -> z (..., latent_dim)``.

    ``h₁ = σ(W₁x + b₁)``, ``h₂ = h₁ + σ(W₂h₁ + b₂)``, ``h₃ = h₂ + σ(W₃h₂ + b₃)``,
    ``z = W₄h₃ + b₄``: 1568 → 200 → 200 → 200 → 2 by default (two 28 × 28 frames,
    flattened row-major and concatenated, in; ``(q, p)``-like latent out).

    Args:
        input_dim: length of the flattened input (``2·28² = 1568``).
        hidden_dim: width of the three hidden layers.
        latent_dim: length of the latent code.
        activation: ``"relu"`` (reference, pixel task) or ``"tanh"`` (the class's
            default in the reference).
    """

    def __init__(
        self,
        input_dim: int = 1568,
        hidden_dim: int = 200,
        latent_dim: int = 2,
        activation: str = "relu",
    ) -> None:
        super().__init__()
        self._act = _check(activation)
        self.activation = activation
        self.linear1 = nn.Linear(input_dim, hidden_dim)
        self.linear2 = nn.Linear(hidden_dim, hidden_dim)
        self.linear3 = nn.Linear(hidden_dim, hidden_dim)
        self.linear4 = nn.Linear(hidden_dim, latent_dim)
        for layer in (self.linear1, self.linear2, self.linear3, self.linear4):
            nn.init.orthogonal_(layer.weight)

    def forward(self, x: Tensor) -> Tensor:
        h = self._act(self.linear1(x))
        h = h + self._act(self.linear2(h))
        h = h + self._act(self.linear3(h))
        return self.linear4(h)


class PixelDecoder(nn.Module):
    """``z (..., latent_dim) -> x̂ (..., output_dim)``, the encoder's mirror image.

    ``h₁ = σ(W₅z + b₅)``, ``h₂ = h₁ + σ(W₆h₁ + b₆)``, ``h₃ = h₂ + σ(W₇h₂ + b₇)``,
    ``x̂ = W₈h₃ + b₈``: 2 → 200 → 200 → 200 → 1568 by default; the output is linear
    (no sigmoid), as in the reference.

    Args:
        latent_dim: length of the latent code.
        hidden_dim: width of the three hidden layers.
        output_dim: length of the flattened reconstruction (``2·28² = 1568``).
        activation: ``"relu"`` (reference, pixel task) or ``"tanh"``.
    """

    def __init__(
        self,
        latent_dim: int = 2,
        hidden_dim: int = 200,
        output_dim: int = 1568,
        activation: str = "relu",
    ) -> None:
        super().__init__()
        self._act = _check(activation)
        self.activation = activation
        self.linear5 = nn.Linear(latent_dim, hidden_dim)
        self.linear6 = nn.Linear(hidden_dim, hidden_dim)
        self.linear7 = nn.Linear(hidden_dim, hidden_dim)
        self.linear8 = nn.Linear(hidden_dim, output_dim)
        for layer in (self.linear5, self.linear6, self.linear7, self.linear8):
            nn.init.orthogonal_(layer.weight)

    def forward(self, z: Tensor) -> Tensor:
        h = self._act(self.linear5(z))
        h = h + self._act(self.linear6(h))
        h = h + self._act(self.linear7(h))
        return self.linear8(h)
