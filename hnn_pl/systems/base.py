"""The interface every physical system implements.

A state is ``y = cat([q, p], -1)`` with shape ``(..., 2k)`` for ``k`` degrees of
freedom; batch dimensions come first. The symplectic matrix is
``J = [[0, I], [-I, 0]]`` so Hamilton's equations read ``dy/dt = J ∇H(y)``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch
from torch import Tensor

from hnn_pl.integrate import odeint


def symplectic_gradient(grad_h: Tensor) -> Tensor:
    """``J ∇H = (∂H/∂p, −∂H/∂q)`` for a gradient of shape ``(..., 2k)``."""
    dh_dq, dh_dp = grad_h.chunk(2, dim=-1)
    return torch.cat([dh_dp, -dh_dq], dim=-1)


def system_spec(system: object) -> dict:
    """``{"class_path": "module.Class", "init_args": {…}}`` of a system: its full import
    path (the data cache keys on it) and its parameters, JSON-ready."""
    cls = type(system)
    params = {
        k: list(v) if isinstance(v, tuple) else v
        for k, v in vars(system).items()
        if not k.startswith("_")
    }
    return {"class_path": f"{cls.__module__}.{cls.__qualname__}", "init_args": params}


def unit_and_radius(
    n: int, radius: tuple[float, float], generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """The reference's draw of a point in an annulus, float64: a direction ``(n, 2)``,
    ``U[-1, 1]²`` normalised (not uniform in angle), and a radius ``(n, 1)``,
    ``U[r_min, r_max]``."""
    d = torch.rand(n, 2, generator=generator, dtype=torch.float64) * 2 - 1
    r = torch.rand(n, 1, generator=generator, dtype=torch.float64)
    return d / d.norm(dim=-1, keepdim=True), r * (radius[1] - radius[0]) + radius[0]


def sample_annulus(n: int, radius: tuple[float, float], generator: torch.Generator) -> Tensor:
    """States ``(n, 2)``: :func:`unit_and_radius`'s direction times its radius."""
    u, r = unit_and_radius(n, radius, generator)
    return u * r


class HamiltonianSystem(ABC):
    """A conservative system ``dy/dt = J ∇H(y)`` with a known ``H``.

    Subclasses set ``dof`` (degrees of freedom ``k``) and implement :meth:`hamiltonian`
    and :meth:`sample_initial`; that is a whole new system (the vector field then comes
    from autograd of ``H``). They may override :meth:`vector_field` with a closed form
    (faster), :meth:`energy` (the physical energy the metrics compare, by default ``H``)
    and :meth:`exact_solution`. The data cache keys on the class's full import path.
    """

    dof: int = 1
    #: tolerances of the float64 ground-truth integration (overridable per system)
    rtol: float = 1e-10
    atol: float = 1e-10

    @property
    def state_dim(self) -> int:
        """``2k``: the length of the last axis of a state."""
        return 2 * self.dof

    @abstractmethod
    def hamiltonian(self, y: Tensor) -> Tensor:
        """``H(y)``: shape ``(..., 2k) -> (...)``."""

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``dy/dt = J ∇H(y)``, shape ``(..., 2k) -> (..., 2k)``: by autograd of
        :meth:`hamiltonian` over the whole batch at once (``H`` of independent rows sums
        to a scalar whose gradient is every row's ``∇H``), in ``y``'s dtype, under any
        grad mode including inference mode. Subclasses may give the closed form."""
        with torch.inference_mode(False), torch.enable_grad():
            x = y.detach().clone().requires_grad_(True)
            (grad,) = torch.autograd.grad(self.hamiltonian(x).sum(), x)
        return symplectic_gradient(grad)

    def energy(self, y: Tensor) -> Tensor:
        """The physical energy used by the metrics, ``(..., 2k) -> (...)``. Default ``H``."""
        return self.hamiltonian(y)

    @abstractmethod
    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        """Draw ``n`` initial states, float64, shape ``(n, 2k)``, from ``generator``."""

    def exact_solution(self, t: Tensor, y0: Tensor) -> Tensor | None:
        """Closed-form ``y(t)`` of shape ``(T, n, 2k)`` for ``y0 (n, 2k)``, or ``None``."""
        return None

    def trajectory(self, y0: Tensor, t: Tensor) -> Tensor:
        """Ground truth ``y(t) (T, n, 2k)`` in ``y0``'s dtype, computed in float64: the
        closed form where there is one, else ``dopri5`` at the system's ``rtol``/``atol``."""
        y64, t64 = y0.to(torch.float64), t.to(torch.float64)
        out = self.exact_solution(t64, y64)
        if out is None:
            out = odeint(
                self.vector_field, y64, t64, method="dopri5", rtol=self.rtol, atol=self.atol
            )
        return out.to(y0.dtype)
