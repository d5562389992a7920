"""The published energy-MSE procedure of a state task, run on a prepared case.

A :class:`ReferenceCase` is a :class:`~hnn_pl.evaluation.protocols.ReferenceProtocol`'s
starts, times and truth (scipy RK45), made once and rolled out often (time to accuracy
scores a model every few steps against one case).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from hnn_pl.evaluation.base import Rollout, in_dtype
from hnn_pl.evaluation.contract import StateData
from hnn_pl.integrate import odeint, scipy_odeint


def _q2p2(y: Tensor) -> Tensor:
    return (y**2).sum(-1)


def _box_starts(p: Any, dim: int, seed: int) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    mag = torch.rand(p.n_starts, dim, generator=g, dtype=torch.float64)
    sign = torch.randint(0, 2, (p.n_starts, dim), generator=g).double() * 2 - 1
    return sign * (p.box_low + (p.box_high - p.box_low) * mag)


def _scipy_rollout(f, y0: Tensor, t: Tensor, p: Any, stretch: Tensor | None = None) -> Tensor:
    """One ``solve_ivp`` RK45 call on the flattened batch; ``stretch (n,)`` scales the
    field of each trajectory, so trajectory ``k`` is read at times ``stretch_k · t``."""
    field = f
    if stretch is not None:
        c = stretch.to(torch.float64)[:, None]

        def field(s: Tensor, y: Tensor) -> Tensor:
            return c * f(s, y)

    kwargs = {"rtol": p.rtol} if p.atol is None else {"rtol": p.rtol, "atol": p.atol}
    return scipy_odeint(field, y0, t, "RK45", **kwargs)


@dataclass
class ReferenceCase:
    """Trajectories of a reference protocol: ``t (T,)`` float64, starts ``y0 (n, D)``,
    truth ``y_true (T, n, D)``, the models' time factors ``stretch (n,)`` (quirk 1) or
    ``None``, the compared ``energy (..., D) -> (...)``, and ``y_read (T, n, D)``: the
    truth at the times the models' states are read (``stretch_k · t``; ``y_true``
    itself without a stretch), for the state errors."""

    protocol: Any
    t: Tensor
    y0: Tensor
    y_true: Tensor
    stretch: Tensor | None
    energy: Callable[[Tensor], Tensor]
    y_read: Tensor | None = None

    def __post_init__(self) -> None:
        if self.y_read is None:
            self.y_read = self.y_true

    def run(self, model: Any, solver: str = "scipy") -> Rollout:
        """Roll a float64 copy of ``model``'s field out on this case.

        ``solver="scipy"`` is the published procedure (RK45 on the flattened batch);
        ``"torch"`` integrates the same starts, stretch and horizon with the batched
        per-row ``dopri5`` at the protocol's ``rtol`` and ``atol`` (scipy's default 1e-6
        where unset): the same ≈1e-6 accuracy, several times cheaper, for scoring during
        training (rows that diverge stop: see ``status``). The energies compare with
        the unstretched truth (the reference's quirk 1), the states with ``y_read``.
        """
        p, f = self.protocol, in_dtype(getattr(model, "field", model), torch.float64).vector_field
        status = None
        if solver == "torch":
            y_pred, status = self._torch(f, p.solver_kwargs()["atol"])
        elif solver == "scipy":
            y_pred = _scipy_rollout(f, self.y0, self.t, p, self.stretch)
        else:
            raise ValueError(f"solver must be 'scipy' or 'torch', got {solver!r}")
        r = Rollout(self.t, self.y_read, y_pred, self.energy(self.y_true), self.energy(y_pred))
        r.status, r.n_groups = status, p.n_groups
        return r

    def _torch(self, f: Callable, atol: float) -> tuple[Tensor, Tensor]:
        y0, field = self.y0, f
        if self.stretch is not None:  # each row's factor rides along as a constant coordinate

            def field(s: Tensor, yc: Tensor) -> Tensor:
                return torch.cat([yc[:, -1:] * f(s, yc[:, :-1]), torch.zeros_like(yc[:, -1:])], -1)

            y0 = torch.cat([self.y0, self.stretch[:, None]], -1)
        with torch.no_grad():
            sol = odeint(field, y0, self.t, "dopri5", self.protocol.rtol, atol, return_status=True)
        return sol.y[..., : self.y0.shape[-1]], sol.status


def reference_case(dm: StateData, p: Any) -> ReferenceCase:
    """Starts, times and truth of the reference protocol ``p`` on ``dm`` after ``setup``."""
    energy = _q2p2 if p.energy == "q2p2" else dm.energy
    if p.starts == "test":
        t, y_true = dm.test_t.double(), dm.test_y.double()
        return ReferenceCase(p, t, y_true[0], y_true, None, energy)
    if p.starts == "box":
        y0 = _box_starts(p, dm.state_dim, seed=0)
    else:
        gens = [torch.Generator().manual_seed(k) for k in range(p.n_starts)]
        y0 = torch.cat([dm.system.sample_initial(1, g) for g in gens])
    t = torch.linspace(0, p.t_end, p.n_points, dtype=torch.float64)
    y_true = _scipy_rollout(dm.system.vector_field, y0, t, p)
    if p.time_stretch == 1.0:
        return ReferenceCase(p, t, y0, y_true, None, energy)
    k = torch.arange(2, p.n_starts + 2, dtype=torch.float64)
    stretch = p.time_stretch ** (k if p.compound_stretch else torch.ones_like(k))
    y_read = _scipy_rollout(dm.system.vector_field, y0, t, p, stretch)
    return ReferenceCase(p, t, y0, y_true, stretch, energy, y_read)
