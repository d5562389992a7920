"""The one result type of every rollout, and the helpers that integrate a field.

Trajectories are time first, ``(T, B, D)``, as :func:`hnn_pl.odeint` returns them.
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.integrate import Solution, odeint

#: saved name → field of a rollout from given starts (:meth:`Rollout.as_dict`)
SAVED = {"t": "t", "y": "y_pred", "h": "h_pred", "energy": "e_pred", "frames": "x_pred"}
SAVED |= {"status": "status", "t_stop": "t_stop"}


@dataclass
class Rollout:
    """A rollout, with its truth when there is one.

    ``t (T,)``; ``y_true (T, B, D)`` and ``y_pred`` integrated from ``y_true[0]`` (from
    given starts, ``y_true`` is ``None``); energies ``e_true``/``e_pred (T, B)`` (``None``
    without an energy); the learned ``h_pred (T, B)`` (HNN) and ``h_scale`` (std of
    ``H_θ`` over training inputs). Pixel models: ``y``/``e`` are the linear probe's
    ``(q, p) = (θ, c·θ̇)`` (without a probe, ``y_pred`` are the latents);
    ``z_true``/``z_pred (T, B, L)`` encoded and integrated latents, ``x_true``/``x_pred
    (T, B, 1568)`` frame pairs, ``probe (L + 1, 2)`` with ``(q, p) ≈ [z, 1] @ probe`` and
    its training residual ``probe_mse``. ``y_true`` (and ``e_true``) are ``NaN`` at times
    a trajectory was not observed. ``status``/``t_stop (B,)``: each row's
    :class:`hnn_pl.integrate.Status` and stop time (a diverged row is NaN after it).
    ``floors``: the true system's own errors under the protocol (state models).
    ``f_true``/``f_pred (T, B, D)``: the true field and ``f_θ`` on the true states
    (state models whose data gives one). ``n_groups``: groups of the "±".
    ``positions``: ``k`` when the starts were inferred from observed positions (the
    momenta are the model's own gauge): the scores are then the gauge-invariant ones on
    the first ``k`` coordinates, and ``e_pred`` the true energy from ``(q, q̇)``.
    """

    t: Tensor
    y_true: Tensor | None
    y_pred: Tensor | None = None
    e_true: Tensor | None = None
    e_pred: Tensor | None = None
    h_pred: Tensor | None = None
    h_scale: Tensor | float = 0.0
    z_true: Tensor | None = None
    z_pred: Tensor | None = None
    x_true: Tensor | None = None
    x_pred: Tensor | None = None
    probe: Tensor | None = None
    probe_mse: Tensor | float = 0.0
    status: Tensor | None = None
    t_stop: Tensor | None = None
    floors: dict[str, Tensor] | None = None
    f_true: Tensor | None = None
    f_pred: Tensor | None = None
    n_groups: int = 5
    positions: int | None = None

    #: the fields indexed ``[:, row]``
    PER_ROW = ("y_true", "y_pred", "e_true", "e_pred", "h_pred", "z_true", "z_pred")
    PER_ROW += ("x_true", "x_pred", "f_true", "f_pred")

    @property
    def has_frames(self) -> bool:
        """Whether the rollout was decoded to frames (a pixel model's)."""
        return self.x_pred is not None

    def rows(self, keep: Tensor) -> Rollout:
        """The rollout of the rows ``keep (B,)`` (bool) only."""
        picked = {
            k: getattr(self, k)[:, keep] for k in self.PER_ROW if getattr(self, k) is not None
        }
        status = None if self.status is None else self.status[keep]
        t_stop = None if self.t_stop is None else self.t_stop[keep]
        floors = None if self.floors is None else {k: v[keep] for k, v in self.floors.items()}
        return replace(self, **picked, status=status, t_stop=t_stop, floors=floors)

    def as_dict(self) -> dict[str, Tensor]:
        """A rollout from given starts as ``predict --starts`` and ``bump`` save it: ``t``,
        ``y``, ``h`` (HNN), ``energy``, ``frames`` (pixel), ``status``, ``t_stop``; the
        fields that are set, on the CPU."""
        out = {k: getattr(self, v) for k, v in SAVED.items()}
        return {k: v.cpu() for k, v in out.items() if v is not None}


def as_dtype(dtype: str | torch.dtype | None) -> torch.dtype | None:
    """``"float64"`` → ``torch.float64``; ``"model"`` → ``None`` (the model's own)."""
    if isinstance(dtype, str):
        return None if dtype == "model" else getattr(torch, dtype)
    return dtype


def in_dtype(module: nn.Module, dtype: str | torch.dtype | None) -> nn.Module:
    """``module`` itself, or a copy in ``dtype`` (``"float64"``, a torch dtype; ``None``
    or ``"model"``: as is) when its parameters are in another."""
    dtype = as_dtype(dtype)
    param = next(module.parameters(), None)
    if dtype is None or param is None or param.dtype == dtype:
        return module
    return copy.deepcopy(module).to(dtype)


@contextlib.contextmanager
def eval_mode(*modules: Any) -> Iterator[None]:
    """Put ``modules`` (``nn.Module``s; others are ignored) in eval mode and without
    gradients, and restore each one's mode afterwards."""
    modules = tuple(m for m in modules if isinstance(m, nn.Module))
    was = [m.training for m in modules]
    for m in modules:
        m.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        for m, training in zip(modules, was):
            m.train(training)


def integrate_field(
    field: nn.Module, y0: Tensor, t: Tensor, dtype: str | torch.dtype | None = "float64", **kw
) -> tuple[Solution, nn.Module]:
    """The :class:`~hnn_pl.integrate.Solution` of ``field.vector_field`` from ``y0 (B, D)``
    over ``t (T,)`` (states ``(T, B, D)``; a row that diverges stops alone) and the field
    used: :func:`in_dtype` of ``field`` (float64 keeps the rollout's error far below the
    model's). ``kw``: ``method``, ``rtol``, ``atol``, ``step_size``, ``options``."""
    field = in_dtype(field, dtype)
    param = next(field.parameters(), None)
    run_dtype = as_dtype(dtype) or (param.dtype if param is not None else y0.dtype)
    with torch.no_grad():
        sol = odeint(
            field.vector_field, y0.to(run_dtype), t.to(run_dtype), return_status=True, **kw
        )
    return sol, field


def learned_h(field: nn.Module, y: Tensor) -> Tensor | None:
    """``H_θ`` along ``y (T, B, D)`` as ``(T, B)``, or ``None`` without ``hamiltonian``."""
    if not hasattr(field, "hamiltonian"):
        return None
    with torch.no_grad():
        return field.hamiltonian(y.flatten(0, 1)).reshape(y.shape[:2])
