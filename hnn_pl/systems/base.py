"""The interface every physical system implements.

A state is ``y = cat([q, p], -1)`` with shape ``(..., 2k)`` for ``k`` degrees of
freedom; batch dimensions come first. The symplectic matrix is
``J = [[0, I], [-I, 0]]`` so Hamilton's equations read ``dy/dt = J ∇H(y)``.
"""

from __future__ import annotations

import hashlib
from abc import ABC, abstractmethod
from pathlib import Path

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


def source_digest(cls: type) -> str | None:
    """SHA-256 (16 hex digits) of the source file defining ``cls`` if it lies outside
    this package (a user's system: editing its ``hamiltonian`` must change the data
    cache's key), else ``None`` (the package's own systems change with
    ``CACHE_VERSION``). Without a source file (a class typed into a session), the
    compiled code of the class's methods."""
    import inspect
    import marshal

    if cls.__module__.split(".")[0] == "hnn_pl":
        return None
    digest = hashlib.sha256()
    try:
        digest.update(Path(inspect.getsourcefile(cls) or "").read_bytes())
    except (TypeError, OSError):
        for name, value in sorted(vars(cls).items()):
            code = getattr(getattr(value, "__func__", value), "__code__", None)
            digest.update(name.encode() + (marshal.dumps(code) if code else repr(value).encode()))
    return digest.hexdigest()[:16]


def check_system(system: HamiltonianSystem, starts: Tensor) -> None:
    """Refuse a system whose sampler or ``H`` would make wrong data, in one
    ``ValueError`` line naming the class: ``starts`` (what ``sample_initial(n, g)``
    returned) must be float64 of shape ``(n, 2·dof)`` and finite; ``hamiltonian`` must
    map them to finite ``(n,)`` and ``vector_field`` to finite ``(n, 2·dof)``."""
    name = system_spec(system)["class_path"]
    D = system.state_dim
    if not isinstance(starts, Tensor):
        raise ValueError(
            f"system {name}: sample_initial returned a {type(starts).__name__}, not a tensor"
        )
    n = starts.shape[0] if starts.ndim else 0
    if starts.shape != (n, D):
        raise ValueError(
            f"system {name}: sample_initial returned shape {tuple(starts.shape)}; expected "
            f"({n}, {D}) = (n, 2·dof) with dof = {system.dof}"
        )
    if starts.dtype != torch.float64:
        raise ValueError(
            f"system {name}: sample_initial returned {starts.dtype}; expected torch.float64"
        )
    _require_finite(name, "sample_initial", starts, starts)
    with torch.no_grad():
        h = system.hamiltonian(starts)
    if not isinstance(h, Tensor) or h.shape != (n,):
        shape = tuple(h.shape) if isinstance(h, Tensor) else type(h).__name__
        raise ValueError(
            f"system {name}: hamiltonian returned {shape} for states of shape ({n}, {D}); "
            f"expected ({n},), one energy per state"
        )
    _require_finite(name, "hamiltonian", h, starts)
    f = system.vector_field(None, starts)
    if not isinstance(f, Tensor) or f.shape != (n, D):
        shape = tuple(f.shape) if isinstance(f, Tensor) else type(f).__name__
        raise ValueError(f"system {name}: vector_field returned {shape}; expected ({n}, {D})")
    _require_finite(name, "vector_field", f, starts)


def _require_finite(name: str, what: str, values: Tensor, starts: Tensor) -> None:
    bad = ~torch.isfinite(values.reshape(values.shape[0], -1)).all(-1)
    if bool(bad.any()):
        first = starts[bad.nonzero()[0, 0]].tolist()
        raise ValueError(
            f"system {name}: {what} is not finite at {int(bad.sum())} of {len(bad)} sampled "
            f"starts (e.g. y = {[float(f'{v:.4g}') for v in first]})"
        )


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

    def momentum_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """The momenta whose velocity is ``v``: ``p`` with ``∂H/∂p (q, p) = v``, shape
        ``(..., k), (..., k) -> (..., k)`` in ``q``'s dtype.

        Assumes ``H`` quadratic in ``p``, ``H = ½ pᵀA(q)p + b(q)ᵀp + V(q)`` with ``A(q)``
        invertible (every bundled system; any mechanical kinetic energy, magnetic terms
        included): then ``∂H/∂p = A(q)p + b(q)`` and ``p = A(q)⁻¹ (v − b(q))``, with
        ``b = ∂H/∂p`` and ``A = ∂²H/∂p²`` at ``(q, 0)`` by autograd of
        :meth:`hamiltonian` over the whole batch at once (``k + 1`` backward passes). For
        another ``H`` this is one Newton step from ``p = 0``; override it with the
        closed form where there is one."""
        k = self.dof
        qf, vf = q.reshape(-1, k), v.reshape(-1, k)
        with torch.inference_mode(False), torch.enable_grad():
            qd = qf.detach().clone()
            p = torch.zeros_like(qd, requires_grad=True)
            h = self.hamiltonian(torch.cat([qd, p], -1))
            (b,) = torch.autograd.grad(h.sum(), p, create_graph=True)
            rows = [
                torch.autograd.grad(b[:, i].sum(), p, retain_graph=True, allow_unused=True)[0]
                for i in range(k)
            ]
        a = torch.stack([torch.zeros_like(qd) if r is None else r for r in rows], 1)
        return torch.linalg.solve(a.detach(), vf - b.detach()).reshape(q.shape)

    def energy_qv(self, q: Tensor, v: Tensor) -> Tensor:
        """The physical energy from positions and velocities,
        ``E(q, q̇) = energy(q, momentum_qv(q, q̇))``: ``(..., k), (..., k) -> (...)``.
        Gauge-invariant: it reads no learned momentum."""
        return self.energy(torch.cat([q, self.momentum_qv(q, v)], -1))
