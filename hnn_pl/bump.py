"""Energy bump (Greydanus et al. 2019, §6): change a trajectory's learned energy ``H_θ``
by a requested amount, then follow the learned dynamics at the new energy.

The bump integrates the normalised gradient flow ``dy/ds = ∇H_θ(y) / |∇H_θ(y)|²``, on
which ``dH_θ/ds = 1``, from ``s = 0`` to ``s = ΔH`` (backward for ``ΔH < 0``), so
``H_θ(y(ΔH)) = H_θ(y₀) + ΔH`` up to the integration's tolerance; the rollout then
integrates ``dy/dt = J ∇H_θ(y)``, which keeps ``H_θ``. ``∇H_θ`` comes from the
field's own ``J ∇H_θ``: with ``J∇H = (∂H/∂p, −∂H/∂q)``, ``∇H = (−(J∇H)_p, (J∇H)_q)``.
Pixel models are bumped in their latent space and decoded.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.evaluation import Rollout, eval_mode, in_dtype, rollout, view_of
from hnn_pl.integrate import odeint


class GradientFlow(nn.Module):
    """``dy/ds = ∇H_θ / |∇H_θ|²`` of a Hamiltonian field (``(B, D) -> (B, D)``)."""

    def __init__(self, field: nn.Module) -> None:
        super().__init__()
        self.field = field

    def vector_field(self, s: Tensor, y: Tensor) -> Tensor:
        f = self.field.vector_field(s, y)
        k = f.shape[-1] // 2
        grad = torch.cat([-f[..., k:], f[..., :k]], -1)
        return grad / grad.square().sum(-1, keepdim=True).clamp_min(1e-300)


def energy_bump(
    model: Any,
    y0: Tensor,
    delta: float,
    t: Tensor,
    method: str = "dopri5",
    rtol: float = 1e-10,
    atol: float = 1e-10,
) -> tuple[Tensor, Rollout]:
    """Bump ``H_θ`` of each start by ``delta``, then roll out over ``t``.

    Args:
        model: an HNN (state or pixel); its field must have ``hamiltonian``.
        y0: ``(B, D)`` states, or ``(B, input_dim)`` frame pairs for a pixel model.
        delta: the change of ``H_θ``.
        t: ``(T,)`` rollout times after the bump.
        method, rtol, atol: the rollout's integrator (the bump uses float64 dopri5 at
            ``rtol``/``atol``).

    Returns:
        ``(z_bumped (B, D), rollout)``: the bumped (latent) states, float64, and the
        rollout from them (:class:`hnn_pl.evaluation.Rollout`; ``h_pred`` is ``H_θ``
        along it, pixel models also ``x_pred``, the decoded frames).
    """
    view = view_of(model)
    if not hasattr(view.field, "hamiltonian"):
        raise ValueError(f"{type(model).__name__} learns no H_θ: only HNN models can be bumped")
    with eval_mode(model):
        z0 = view.encode(y0).double()
        z1 = z0 if delta == 0 else _flow(in_dtype(view.field, torch.float64), z0, delta, rtol, atol)
    return z1, rollout(model, z1, t, method, rtol=rtol, atol=atol, encode=False)


def _flow(field64: nn.Module, z0: Tensor, delta: float, rtol: float, atol: float) -> Tensor:
    """``z0 (B, D)`` moved along :class:`GradientFlow` over ``s ∈ [0, delta]``."""
    s = torch.tensor([0.0, float(delta)], dtype=torch.float64)
    sol = odeint(
        GradientFlow(field64).vector_field, z0, s, rtol=rtol, atol=atol, return_status=True
    )
    if not bool(sol.ok.all()):
        rows = (~sol.ok).nonzero().flatten().tolist()
        first = float(sol.t_stop[~sol.ok].min())
        raise ValueError(
            f"energy bump: rows {rows[:5]} meet a critical point of H_θ before it "
            f"changes by {delta:g} (first at ΔH_θ = {first:.3g}); use a smaller |delta|"
        )
    return sol.y[-1]


def default_delta(h0: Tensor, share: float = 0.2) -> float:
    """The bump asked for when none is given: ``share · (max H − min H + mean |H|)`` of
    ``H_θ`` at the starts, ``h0 (B,)`` (a share of their spread, and of their size when
    they share one energy)."""
    return share * float(h0.max() - h0.min() + h0.abs().mean())


def bump_and_roll_out(
    model: Any, starts: Tensor, delta: float | None, t: Tensor, share: float = 0.2
) -> tuple[float, Rollout, Rollout]:
    """``starts`` rolled out over ``t (T,)`` as they are and bumped by ``delta``
    (``None``: :func:`default_delta` with ``share``): ``(delta, before, after)``."""
    _, before = energy_bump(model, starts, 0.0, t)
    delta = default_delta(before.h_pred[0], share) if delta is None else delta
    _, after = energy_bump(model, starts, delta, t)
    return delta, before, after
