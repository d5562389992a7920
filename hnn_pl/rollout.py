"""Rollout metrics: integrate a learned field and compare it with the truth.

Shared by the rollout callback and the evaluation protocols. Trajectories are time
first, ``(T, B, D)``, as :func:`hnn_pl.odeint` returns them.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from hnn_pl.integrate import odeint


@dataclass
class Rollout:
    """A rollout and its truth.

    Attributes:
        t: ``(T,)`` times.
        y_true: ``(T, B, D)`` true states.
        y_pred: ``(T, B, D)`` integrated learned field from ``y_true[0]``.
        e_true, e_pred: ``(T, B)`` physical energy along each.
        h_pred: ``(T, B)`` the learned ``H_θ`` along ``y_pred`` (HNN only), else ``None``.
        h_scale: the standard deviation of ``H_θ`` over reference inputs (or 0).
    """

    t: Tensor
    y_true: Tensor
    y_pred: Tensor
    e_true: Tensor
    e_pred: Tensor
    h_pred: Tensor | None = None
    h_scale: Tensor | float = 0.0


def integrate_field(
    field: nn.Module,
    y0: Tensor,
    t: Tensor,
    method: str = "dopri5",
    dtype: torch.dtype | None = torch.float64,
    **kwargs,
) -> tuple[Tensor, nn.Module]:
    """Integrate ``field.vector_field`` from ``y0 (B, D)`` over ``t (T,)``.

    With ``dtype`` set (float64 by default) a copy of the field in that dtype is
    integrated, so the rollout's own error stays far below the model's. Runs under
    ``torch.no_grad``.

    Returns:
        ``(T, B, D)`` states in ``dtype`` and the field that produced them.
    """
    param = next(field.parameters(), None)
    if dtype is not None and param is not None and param.dtype != dtype:
        field = copy.deepcopy(field).to(dtype)
    dtype = dtype or y0.dtype
    with torch.no_grad():
        y = odeint(field.vector_field, y0.to(dtype), t.to(dtype), method=method, **kwargs)
    return y, field


def rollout(
    field: nn.Module,
    t: Tensor,
    y_true: Tensor,
    energy: Callable[[Tensor], Tensor],
    method: str = "dopri5",
    dtype: torch.dtype | None = torch.float64,
    scale_inputs: Tensor | None = None,
    **kwargs,
) -> Rollout:
    """Roll ``field`` out from ``y_true[0]`` and evaluate energies along both paths.

    Args:
        field: a module with ``vector_field(t, y)`` (and ``hamiltonian(y)`` for an HNN).
        t: ``(T,)``.
        y_true: ``(T, B, D)``.
        energy: the system's energy, ``(..., D) -> (...)``.
        method, kwargs: passed to :func:`hnn_pl.odeint`.
        dtype: the rollout's dtype (see :func:`integrate_field`).
        scale_inputs: ``(N, D)`` states (e.g. training inputs) over which the spread
            of ``H_θ`` is measured for :func:`conserved_drift`.
    """
    y_pred, field = integrate_field(field, y_true[0], t, method=method, dtype=dtype, **kwargs)
    y_true = y_true.to(y_pred.dtype)
    r = Rollout(t, y_true, y_pred, energy(y_true), energy(y_pred))
    if hasattr(field, "hamiltonian"):
        with torch.no_grad():
            r.h_pred = field.hamiltonian(y_pred.flatten(0, 1)).reshape(y_pred.shape[:2])
            if scale_inputs is not None:
                r.h_scale = field.hamiltonian(scale_inputs.to(y_pred)).std()
    return r


def energy_mse(r: Rollout) -> Tensor:
    """``mean_{t,b} (E(y_true) − E(y_pred))²``."""
    return ((r.e_true - r.e_pred) ** 2).mean()


def state_mse(r: Rollout) -> Tensor:
    """``mean_{t,b,d} (y_true − y_pred)²``."""
    return ((r.y_true - r.y_pred) ** 2).mean()


def conserved_drift(r: Rollout) -> Tensor:
    """``mean_b max_t |H_θ(y_t) − H_θ(y_0)| / (|H_θ(y_0)| + scale)``.

    ``H_θ`` carries an arbitrary additive constant, so ``|H_θ(y_0)|`` alone is no
    yardstick; ``scale = r.h_scale`` (the rollout callback uses the standard
    deviation of ``H_θ`` over the training inputs) measures the drift against the
    spread of the learned energy over the data.
    """
    h = r.h_pred
    return ((h - h[0]).abs().amax(0) / (h[0].abs() + r.h_scale)).mean()
