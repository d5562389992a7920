"""The multilayer perceptron of the paper, with a closed-form input gradient."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor, nn

_ACTIVATIONS = {"tanh": torch.tanh, "relu": torch.relu, "softplus": nn.functional.softplus}


def activation_fn(name: str, table: dict[str, Callable] = _ACTIVATIONS) -> Callable:
    """``table[name]``, or a ValueError listing the valid names."""
    if name not in table:
        raise ValueError(f"activation must be one of {sorted(table)}, got {name!r}")
    return table[name]


def check_angles(angles: Sequence[int] | None, dof: int) -> tuple[int, ...]:
    """``angles`` as a sorted tuple of distinct configuration indices ``0 ≤ i < dof``
    (``None``: none), or a one-line ``ValueError``."""
    angles = tuple(angles or ())
    if not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < dof for i in angles):
        raise ValueError(
            f"angles must be indices of the coordinates q (0 … {dof - 1}), got {list(angles)}"
        )
    if len(set(angles)) != len(angles):
        raise ValueError(f"angles must be distinct: {list(angles)}")
    return tuple(sorted(angles))


def check_angle_pairs(
    angle_pairs: bool, angles: tuple[int, ...], name: str = "angle_pairs"
) -> None:
    """A one-line ``ValueError`` unless ``angle_pairs`` is a bool, true only with two
    ``angles`` or more (``name``: how the option is spelled in the message)."""
    if not isinstance(angle_pairs, bool) or (angle_pairs and len(angles) < 2):
        raise ValueError(f"{name} needs two angles or more: {list(angles)}")


class MLP(nn.Module):
    """``Linear(d→h) → σ → Linear(h→h) → σ → … → Linear(h→out, no bias)``.

    The reference architecture: orthogonal initialisation of every weight matrix,
    PyTorch's default biases, no bias on the output layer.

    ``angles``: input coordinates that are angles enter as ``(cos x_i, sin x_i)``
    (:meth:`features`, ``d → d + a`` for ``a`` angles), so the network is ``2π``-periodic
    in them exactly, however far an unwrapped angle has turned. ``angle_pairs``: every
    pair ``i < j`` of them enters too as ``(cos, sin)`` of ``x_i − x_j`` and ``x_i + x_j``
    (``2a(a − 1)`` more inputs): the torus's second-order Fourier basis, in which a
    function of one angle difference (a chain's mass matrix) is a function of one input.
    The closed-form input
    derivatives (:meth:`value_and_input_grad`, :meth:`input_vjp`, :meth:`input_jvp`)
    are with respect to the raw input ``x``, through the features.

    Args:
        input_dim: ``d``, the length of the input's last axis.
        output_dim: ``out``.
        hidden_dim: ``h``, the width of each hidden layer.
        n_hidden: number of hidden layers (2 in the paper).
        activation: ``"tanh"`` (paper), ``"relu"`` or ``"softplus"``.
        angles: indices ``i < d`` of the input coordinates read as ``(cos, sin)``.
        angle_pairs: the angles' pairwise differences and sums read as ``(cos, sin)``
            too (needs two angles or more).
    """

    def __init__(
        self,
        input_dim: int,
        output_dim: int,
        hidden_dim: int = 200,
        n_hidden: int = 2,
        activation: str = "tanh",
        angles: Sequence[int] = (),
        angle_pairs: bool = False,
    ) -> None:
        super().__init__()
        self._act = activation_fn(activation)
        self.angles = check_angles(angles, input_dim)
        check_angle_pairs(angle_pairs, self.angles)
        self.angle_pairs = angle_pairs
        rest = [i for i in range(input_dim) if i not in self.angles]
        pairs = torch.combinations(torch.arange(len(self.angles)), 2) if angle_pairs else None
        self.register_buffer("angle_index", torch.tensor(self.angles, dtype=torch.long), False)
        self.register_buffer("rest_index", torch.tensor(rest, dtype=torch.long), False)
        self.register_buffer("pair_index", pairs, False)
        n_pairs = 0 if pairs is None else len(pairs)
        dims = [input_dim + len(self.angles) + 4 * n_pairs] + [hidden_dim] * n_hidden
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.out = nn.Linear(hidden_dim, output_dim, bias=False)
        self.activation = activation
        for layer in [*self.hidden, self.out]:
            nn.init.orthogonal_(layer.weight)

    def features(self, x: Tensor) -> Tensor:
        """The first layer's input ``(x_rest, cos x_A, sin x_A)``, ``x_A`` the
        ``angles``, ``x_rest`` the other coordinates in order, then with ``angle_pairs``
        ``(cos d, sin d, cos s, sin s)`` of the pairs' differences ``d = x_i − x_j`` and sums
        ``s = x_i + x_j``: ``(..., d) -> (..., d + a + 4·pairs)``; ``x`` itself without
        angles."""
        if not self.angles:
            return x
        a = x[..., self.angle_index]
        parts = [x[..., self.rest_index], a.cos(), a.sin()]
        if self.pair_index is not None:
            d, s = self._pair_angles(a)
            parts += [d.cos(), d.sin(), s.cos(), s.sin()]
        return torch.cat(parts, -1)

    def _pair_angles(self, a: Tensor) -> tuple[Tensor, Tensor]:
        """The pairs' ``x_i − x_j`` and ``x_i + x_j`` of the angles ``a (..., a)``."""
        ai, aj = a[..., self.pair_index[:, 0]], a[..., self.pair_index[:, 1]]
        return ai - aj, ai + aj

    def features_vjp(self, x: Tensor, g: Tensor) -> Tensor:
        """``(∂features/∂x)ᵀ g``: ``g (..., d + a + 4·pairs)`` at ``x (..., d)`` to
        ``(..., d)``; an angle's entry is ``−sin x_i · g_cos + cos x_i · g_sin``, plus, for
        each pair it is in, ``±(−sin d · g_cos d + cos d · g_sin d)`` (``+`` first, ``−``
        second of the pair) and ``−sin s · g_cos s + cos s · g_sin s``."""
        if not self.angles:
            return g
        n, m, a = len(self.rest_index), len(self.angles), x[..., self.angle_index]
        g_rest, g_cos, g_sin = g[..., :n], g[..., n : n + m], g[..., n + m : n + 2 * m]
        g_angle = a.cos() * g_sin - a.sin() * g_cos
        if self.pair_index is not None:
            d, s = self._pair_angles(a)
            g_cos_d, g_sin_d, g_cos_s, g_sin_s = g[..., n + 2 * m :].chunk(4, -1)
            from_d = d.cos() * g_sin_d - d.sin() * g_cos_d
            from_s = s.cos() * g_sin_s - s.sin() * g_cos_s
            g_angle = g_angle.index_add(-1, self.pair_index[:, 0], from_d + from_s)
            g_angle = g_angle.index_add(-1, self.pair_index[:, 1], from_s - from_d)
        out = torch.zeros(g.shape[:-1] + x.shape[-1:], dtype=g.dtype, device=g.device)
        out[..., self.rest_index] = g_rest
        out[..., self.angle_index] = g_angle
        return out

    def features_jvp(self, x: Tensor, t: Tensor) -> Tensor:
        """``(∂features/∂x) t``: a tangent ``t (..., d)`` at ``x`` (broadcast against
        it) to ``(..., d + a + 4·pairs)``; an angle's pair is ``(−sin x_i, cos x_i) t_i``, a
        difference's ``(−sin d, cos d)(t_i − t_j)``, a sum's ``(−sin s, cos s)(t_i + t_j)``."""
        if not self.angles:
            return t
        a, ta = x[..., self.angle_index], t[..., self.angle_index]
        parts = [t[..., self.rest_index], -a.sin() * ta, a.cos() * ta]
        if self.pair_index is not None:
            (d, s), (td, ts) = self._pair_angles(a), self._pair_angles(ta)
            parts += [-d.sin() * td, d.cos() * td, -s.sin() * ts, s.cos() * ts]
        return torch.cat(parts, -1)

    def forward(self, x: Tensor) -> Tensor:
        """``(..., d) -> (..., out)``."""
        x = self.features(x)
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
        hs = self.activations(x)
        w = self.out.weight[0]
        value = hs[-1] @ w
        g = (1 - hs[-1] ** 2) * w
        for layer, h_prev in zip(reversed(self.hidden[1:]), reversed(hs[:-1])):
            g = (g @ layer.weight) * (1 - h_prev**2)
        return value, self.features_vjp(x, g @ self.hidden[0].weight)

    def activations(self, x: Tensor) -> list[Tensor]:
        """The hidden layers' outputs ``[h₁, …, h_L]``, each ``(B, h)``: what
        :meth:`input_vjp` and :meth:`input_jvp` reuse (``tanh`` only)."""
        if self.activation != "tanh":
            raise NotImplementedError("closed-form input derivatives are implemented for tanh only")
        hs, h = [], self.features(x)
        for layer in self.hidden:
            h = torch.tanh(layer(h))
            hs.append(h)
        return hs

    def input_vjp(self, hs: list[Tensor], cotangent: Tensor, x: Tensor | None = None) -> Tensor:
        """``(∂f/∂x)ᵀ c`` at the input ``x`` whose :meth:`activations` are ``hs``, in
        closed form (``tanh``): ``c (B, out) -> (B, d)`` (``x`` needed with ``angles``)."""
        g = cotangent @ self.out.weight
        for i in range(len(self.hidden) - 1, -1, -1):
            g = (g * (1 - hs[i] ** 2)) @ self.hidden[i].weight
        return self.features_vjp(self._input(x), g)

    def input_jvp(self, hs: list[Tensor], tangent: Tensor, x: Tensor | None = None) -> Tensor:
        """``(∂f/∂x) u`` at the input ``x`` whose :meth:`activations` are ``hs``, in
        closed form (``tanh``): ``u (B, d) -> (B, out)`` (``x`` needed with ``angles``)."""
        t = self.features_jvp(self._input(x), tangent)
        for layer, h in zip(self.hidden, hs):
            t = (t @ layer.weight.T) * (1 - h**2)
        return t @ self.out.weight.T

    def _input(self, x: Tensor | None) -> Tensor | None:
        if x is None and self.angles:
            raise ValueError("an MLP with angles needs its input x for input derivatives")
        return x
