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

import copy
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.integrate import odeint
from hnn_pl.rollouts import Trajectories, is_pixel_model, rollout


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
) -> tuple[Tensor, Trajectories]:
    """Bump ``H_θ`` of each start by ``delta``, then roll out over ``t``.

    Args:
        model: an HNN (state or pixel); its field must have ``hamiltonian``.
        y0: ``(B, D)`` states, or ``(B, input_dim)`` frame pairs for a pixel model.
        delta: the change of ``H_θ``.
        t: ``(T,)`` rollout times after the bump.
        method, rtol, atol: the rollout's integrator (the bump uses float64 dopri5 at
            ``rtol``/``atol``).

    Returns:
        ``(z_bumped (B, D), trajectories)``: the bumped (latent) states and the rollout
        from them (:class:`hnn_pl.rollouts.Trajectories`; ``h`` is ``H_θ`` along it,
        pixel models also ``frames``).
    """
    field = getattr(model, "field", model)
    if not hasattr(field, "hamiltonian"):
        raise ValueError(f"{type(model).__name__} learns no H_θ: only HNN models can be bumped")
    field64 = copy.deepcopy(field).double().eval()
    with torch.no_grad():
        z0 = model.encode(y0) if is_pixel_model(model) else y0
        s = torch.tensor([0.0, float(delta)], dtype=torch.float64)
        if delta == 0:
            z1 = z0.double()
        else:
            flow = GradientFlow(field64)
            sol = odeint(
                flow.vector_field, z0.double(), s, rtol=rtol, atol=atol, return_status=True
            )
            if not bool(sol.ok.all()):
                rows = (~sol.ok).nonzero().flatten().tolist()
                first = float(sol.t_stop[~sol.ok].min())
                raise ValueError(
                    f"energy bump: rows {rows[:5]} meet a critical point of H_θ before it "
                    f"changes by {delta:g} (first at ΔH_θ = {first:.3g}); use a smaller |delta|"
                )
            z1 = sol.y[-1]
    if is_pixel_model(model):
        out = rollout(_LatentModel(model, field64), z1, t, method, rtol=rtol, atol=atol)
    else:
        out = rollout(field64, z1, t, method, rtol=rtol, atol=atol)
    return z1, out


class _LatentModel(nn.Module):
    """A pixel model seen from its latent space: starts are latents, outputs decoded."""

    def __init__(self, model: nn.Module, field: nn.Module) -> None:
        super().__init__()
        self.model, self.field = model, field

    def encode(self, z: Tensor) -> Tensor:
        return z

    def decode(self, z: Tensor) -> Tensor:
        param = next(self.model.parameters())
        return self.model.decode(z.to(param.dtype))
