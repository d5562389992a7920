"""ODE integrators for batches of trajectories, in pure torch.

:func:`odeint` integrates ``dy/dt = func(t, y)`` for a batch of states
``y = cat([q, p], -1)`` of shape ``(batch, dim)`` and returns the states at the
requested times, ``(T, batch, dim)``. Rows are independent trajectories.

=====================  =====  =====================  ===================  ======================
method                 order  symplectic             adaptive             evaluations per step
=====================  =====  =====================  ===================  ======================
``euler``              1      no                     no                   1
``rk4``                4      no                     no                   4
``leapfrog``           2      yes, separable H only  no                   2 (FSAL); +1 at start,
                                                                          +1 separability probe
``implicit_midpoint``  2      yes, any H             no                   1 per fixed-point
                                                                          iteration, typically
                                                                          2-6; +1 at start
``dopri5``             5(4)   no                     yes, per trajectory  6 per attempted step
                                                                          (FSAL); +2 at start
=====================  =====  =====================  ===================  ======================

Fixed-step methods take one step per output interval, or cut each interval into
``ceil(|Δt| / step_size)`` equal steps so that outputs land exactly on ``t``; a ratio
within float32 rounding of an integer counts as that integer, so a grid built in
float32 (``linspace(0, 20, 201)``, ``step_size=0.1``) takes one step per interval.
``dopri5`` controls the error of every trajectory separately (see :class:`Dopri5`).

Containment: a row that starts non-finite stops at once (:attr:`Status.DIVERGED` at
``t[0]``, whatever the field returns there); a row whose state turns non-finite or
exceeds ``blowup · (1 + |y0|∞)``,
whose implicit iteration fails, or whose adaptive step underflows, stalls (steps no
longer change the state: a tolerance below the dtype's resolution), turns stiff or
runs out of steps stops alone; the other rows are as in a run without it (exactly;
dopri5: to the rounding of batched kernels, ≈1e-15 in float64).
``odeint(..., return_status=True)`` returns a :class:`Solution` (states, NaN after a
row stopped, a :class:`Status` per row and the time it stopped); otherwise any
stopped row raises ``RuntimeError`` with the rows, times and reasons.

Backward integration (decreasing ``t``) substitutes ``s = -t``, integrating
``dy/ds = -func(-s, y)`` forward. Gradients flow to ``y0`` and to parameters used by
``func`` (discretise-then-optimise); ``t`` is treated as data.
"""

from __future__ import annotations

import enum
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple

import torch
from torch import Tensor

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "METHODS",
    "Dopri5",
    "Euler",
    "ImplicitMidpoint",
    "Leapfrog",
    "RK4",
    "Solution",
    "Status",
    "odeint",
    "odeint_windows",
    "WINDOW_METHODS",
    "scipy_fun",
    "scipy_odeint",
]

Field = Callable[[Tensor, Tensor], Tensor]

_SEPARABILITY_TOL = 1e-6
_CHECK_EVERY = 16  # dopri5 checks blow-up, stalls and stiffness every this many steps
_STALL_CHECKS = 8  # consecutive checked steps that do not change the state
_PROBE_ROWS = 64


class Status(enum.IntEnum):
    """Why a row of :func:`odeint` stopped (``OK``: it reached the last time)."""

    OK = 0
    DIVERGED = 1  # started or became non-finite, or |y| beyond blowup · (1 + |y0|)
    NOT_CONVERGED = 2  # implicit_midpoint's fixed-point iteration
    STEP_UNDERFLOW = 3  # dopri5: the step size fell below the resolution of t
    STALLED = 4  # dopri5: accepted steps no longer change the state
    STIFF = 5  # dopri5: steps limited by stability, not accuracy
    MAX_STEPS = 6  # dopri5: options["max_steps"] attempted steps

    @property
    def hint(self) -> str:
        return _HINTS[self]


_HINTS = {
    Status.OK: "",
    Status.DIVERGED: "the state started or became non-finite, or blew up",
    Status.NOT_CONVERGED: "the implicit iteration did not converge: use a smaller step_size "
    "(it contracts only for h * Lipschitz(f) / 2 < 1)",
    Status.STEP_UNDERFLOW: "step size underflow: a singularity or a field that is non-finite there",
    Status.STALLED: "steps no longer change the state: rtol/atol are below the dtype's "
    "resolution (float32 cannot reach rtol much below 1e-6)",
    Status.STIFF: "the problem is stiff here (steps limited by stability, h·λ > 3.25): use an "
    "implicit stiff solver, e.g. scipy_odeint(..., method='Radau')",
    Status.MAX_STEPS: "more than max_steps steps (raise options={'max_steps': n})",
}


@dataclass
class Solution:
    """What ``odeint(..., return_status=True)`` returns.

    ``y``: ``(T, B, D)`` states, NaN from the first output after a row stopped;
    ``status``: ``(B,)`` :class:`Status` codes; ``t_stop``: ``(B,)`` float64 time at
    which each row stopped (NaN for rows that reached the end).
    """

    y: Tensor
    status: Tensor
    t_stop: Tensor

    @property
    def ok(self) -> Tensor:
        """``(B,)`` bool: rows that reached the last time."""
        return self.status == Status.OK

    def describe(self, method: str = "") -> str:
        """One line per reason: how many rows, which, from when, and what to do."""
        lines = []
        for code in sorted(set(self.status.reshape(-1).tolist()) - {Status.OK}):
            rows = (self.status.reshape(-1) == code).nonzero().flatten()
            times = self.t_stop.reshape(-1)[rows]
            first = rows[times.argmin()]
            lines.append(
                f"{method + ': ' if method else ''}{len(rows)} of {self.status.numel()} rows "
                f"stopped ({Status(code).name.lower()}; rows {rows[:5].tolist()}"
                f"{'...' if len(rows) > 5 else ''}; first at t = "
                f"{float(self.t_stop.reshape(-1)[first]):.6g}): {Status(code).hint}."
            )
        return "\n".join(lines)


class _Rows:
    """Per-row bookkeeping of one integration: ``status (B,)``, ``t_stop (B,)``,
    ``alive (B,)`` and the blow-up limit ``blowup · (1 + |y0|∞)``. Stop times are
    ``sign · t``: ``sign = -1.0`` while integrating backward (``s = -t``)."""

    def __init__(self, y0: Tensor, blowup: float, sign: float = 1.0) -> None:
        B = y0.shape[0]
        self.status = torch.zeros(B, dtype=torch.long, device=y0.device)
        self.t_stop = torch.full((B,), math.nan, dtype=torch.float64, device=y0.device)
        self.alive = torch.ones(B, dtype=torch.bool, device=y0.device)
        big = torch.finfo(y0.dtype).max
        self.limit = (blowup * (1 + y0.detach().abs().amax(-1))).clamp(max=big)
        self.lowest = float(self.limit.min())
        self.any_stopped = False
        self.sign = sign

    def bad(self, y: Tensor) -> Tensor:
        """``(B,)`` rows whose state is non-finite or beyond the limit."""
        return ~(y.detach().abs().amax(-1) <= self.limit)

    def stop(self, rows: Tensor, code: Status, t: float | Tensor, idx: Tensor | None = None):
        """Stop the alive ``rows`` (``(B,)`` bool) with ``code`` at time ``t`` (a float);
        given ``idx (A,)``, ``rows`` and ``t`` are ``(A,)``, of the batch rows ``idx``."""
        if idx is not None:
            B = self.alive.shape[0]
            rows, t = (x.new_zeros(B).index_put((idx,), x) for x in (rows, t))
        new = rows & self.alive
        self.any_stopped = self.any_stopped or bool(new.any())
        self.status = torch.where(new, int(code), self.status)
        self.t_stop = torch.where(new, self.sign * t, self.t_stop)
        self.alive = self.alive & ~rows


class _Solver:
    """Base of all methods (arguments as :func:`odeint`; unknown options raise).

    ``order``: global error ``O(h^order)``; ``defaults``: the options and their defaults.
    """

    order: int = 0
    defaults: dict[str, Any] = {}

    def __init__(
        self, rtol: float, atol: float, step_size: float | None, options: dict[str, Any] | None
    ) -> None:
        unknown = sorted(set(options or {}) - set(self.defaults))
        if unknown:
            raise ValueError(
                f"{type(self).__name__}: unknown options {unknown}; valid: {sorted(self.defaults)}"
            )
        self.rtol, self.atol, self.step_size = rtol, atol, step_size
        self.options = {**self.defaults, **(options or {})}

    def integrate(
        self, func: Field, y0: Tensor, t: Tensor, blowup: float = 1e6, sign: float = 1.0
    ) -> Solution:
        """States at ``t``: ``y0 (B, D)``, increasing ``t (T,)`` -> ``(T, B, D)`` with
        each row's status; ``blowup`` as :func:`odeint`, ``sign`` as :class:`_Rows`."""
        raise NotImplementedError


class _FixedStep(_Solver):
    """A fixed-step method: subclasses implement :meth:`step`."""

    def step(
        self, func: Field, t: Tensor, y: Tensor, h: float, cache: Any, rows: _Rows
    ) -> tuple[Tensor, Any]:
        """One step ``y (B, D)`` at 0-d ``t`` -> ``(y(t + h), cache)``, ``h > 0``; ``cache``
        is what ``_start`` or the previous step returned (e.g. an FSAL evaluation); a
        row whose step fails stops in ``rows``."""
        raise NotImplementedError

    def _start(self, func: Field, t0: Tensor, y0: Tensor) -> Any:
        return None

    def integrate(self, func, y0, t, blowup=1e6, sign=1.0):
        ts = t.tolist()
        eps = torch.finfo(torch.float32).eps
        rows = _Rows(y0, blowup, sign)
        cache = self._start(func, t[0], y0)
        y, ys = y0, [y0]
        for t_a, t_b in zip(ts[:-1], ts[1:], strict=True):
            n = 1
            if self.step_size is not None:
                slack = 8 * eps * max(abs(t_a), abs(t_b)) / self.step_size
                n = max(1, math.ceil((t_b - t_a) / self.step_size - slack))
            h = (t_b - t_a) / n
            for k in range(n):
                tk = torch.tensor(t_a + k * h, dtype=y0.dtype, device=y0.device)
                y_new, cache = self.step(func, tk, y, h, cache, rows)
                if rows.any_stopped or not float(y_new.detach().abs().max()) <= rows.lowest:
                    rows.stop(rows.bad(y_new), Status.DIVERGED, t_a + (k + 1) * h)
                    y_new = torch.where(rows.alive[:, None], y_new, y)
                y = y_new
            ys.append(torch.where(rows.alive[:, None], y, math.nan) if rows.any_stopped else y)
        return Solution(torch.stack(ys), rows.status, rows.t_stop)


class Euler(_FixedStep):
    """Explicit Euler: ``y1 = y0 + h f(t, y0)``."""

    order = 1

    def step(self, func, t, y, h, cache, rows):
        return y + h * func(t, y), None


class RK4(_FixedStep):
    """Classic Runge-Kutta: ``y1 = y0 + h (k1 + 2 k2 + 2 k3 + k4) / 6``."""

    order = 4

    def step(self, func, t, y, h, cache, rows):
        k1 = func(t, y)
        k2 = func(t + h / 2, y + (h / 2) * k1)
        k3 = func(t + h / 2, y + (h / 2) * k2)
        k4 = func(t + h, y + h * k3)
        return y + (h / 6) * (k1 + 2 * (k2 + k3) + k4), None


class Leapfrog(_FixedStep):
    """Störmer-Verlet, kick-drift-kick, for ``y = (q, p)`` with ``D = 2k``.

    ``p½ = p + h/2 ṗ(q)``, ``q1 = q + h q̇(p½)``, ``p1 = p½ + h/2 ṗ(q1)``, where ``q̇``
    and ``ṗ`` are the first and second half of ``func``'s output. Symplectic and of
    order 2 only for a separable ``H = T(p) + V(q)`` (``q̇`` depends only on ``p``,
    ``ṗ`` only on ``q``); the last kick's evaluation at ``(q1, p½)`` is reused by the
    next step. Option ``check_separable`` (default ``True``): first probe up to 64 rows
    and warn if ``q̇`` changes with ``q`` or ``ṗ`` with ``p`` by more than 1e-6 of the
    cross terms.
    """

    order = 2
    defaults = {"check_separable": True}

    def _start(self, func, t0, y0):
        if y0.shape[-1] % 2:
            raise ValueError(f"leapfrog needs an even state dimension (q, p), got {y0.shape[-1]}")
        f0 = func(t0, y0)
        if self.options["check_separable"]:
            coupling = _non_separability(func, t0, y0, f0)
            if not coupling <= _SEPARABILITY_TOL:
                warnings.warn(
                    "leapfrog assumes a separable H = T(p) + V(q), but this field couples q "
                    f"and p (relative coupling {coupling:.2e}): it is then neither symplectic "
                    "nor second order. Use method='implicit_midpoint', or "
                    "options={'check_separable': False} to skip this check.",
                    UserWarning,
                    stacklevel=5,
                )
        return f0[..., y0.shape[-1] // 2 :]

    def step(self, func, t, y, h, cache, rows):
        q, p = y.chunk(2, dim=-1)
        k = q.shape[-1]
        p_half = p + (h / 2) * cache
        q1 = q + h * func(t + h / 2, torch.cat([q, p_half], -1))[..., :k]
        dp1 = func(t + h, torch.cat([q1, p_half], -1))[..., k:]
        return torch.cat([q1, p_half + (h / 2) * dp1], -1), dp1


def _non_separability(func: Field, t0: Tensor, y0: Tensor, f0: Tensor) -> float:
    """``(‖Δq q̇‖ + ‖Δp ṗ‖) / (‖Δq ṗ‖ + ‖Δp q̇‖)`` for relative perturbations of 1e-3
    (``Δq q̇``: change of ``q̇`` when ``q`` is perturbed), in one call on ``2 n`` rows."""
    with torch.no_grad():
        y, f = y0[:_PROBE_ROWS].detach(), f0[:_PROBE_ROWS].detach()
        n, k = y.shape[0], y.shape[-1] // 2
        scale = y.abs().amax(-1, keepdim=True)
        scale = torch.where(scale > 0, scale, torch.ones_like(scale))
        gen = torch.Generator().manual_seed(0)
        r = torch.rand(y.shape, generator=gen, dtype=y.dtype).to(y.device) + 0.5
        dy = 1e-3 * scale * r
        zero = torch.zeros_like(dy[:, :k])
        dq, dp = torch.cat([dy[:, :k], zero], -1), torch.cat([zero, dy[:, k:]], -1)
        fq, fp = (func(t0, torch.cat([y + dq, y + dp])) - f.repeat(2, 1)).split(n)
        direct = fq[:, :k].norm() + fp[:, k:].norm()
        cross = fq[:, k:].norm() + fp[:, :k].norm()
        if direct == 0:
            return 0.0
        return float(direct / cross)


class ImplicitMidpoint(_FixedStep):
    """Implicit midpoint rule ``y1 = y0 + h f(t + h/2, (y0 + y1)/2)``.

    Symplectic for any ``H`` and symmetric. Solved per step by fixed-point iteration
    on ``k = f(t + h/2, y0 + h/2 k)``, started from the linear extrapolation of the
    last two steps' ``k`` (explicit Euler on the first step). A row has converged
    once ``|Δy1| = h |Δk| <= max(atol + rtol |y1|, 8 eps (1 + |y1|))`` elementwise
    (``y1`` of the predictor); converged rows are frozen, the iteration ends when
    all have converged. It contracts only for ``h L / 2 < 1`` (``L`` the field's
    Lipschitz constant): a row that does not converge in option ``max_iters``
    (default 50) iterations stops with :attr:`Status.NOT_CONVERGED`.
    """

    order = 2
    defaults = {"max_iters": 50}

    def _start(self, func, t0, y0):
        return func(t0, y0), 0.0, None, 0.0

    def step(self, func, t, y, h, cache, rows):
        k, h_prev, k_old, spacing = cache
        if k_old is not None:
            ratio = (h_prev + h) / (2 * spacing)
            if isinstance(ratio, Tensor):  # per-row steps: a row at rest (h = 0) keeps k
                ratio = torch.nan_to_num(ratio, nan=0.0, posinf=0.0)
            k = _axpy(k, k - k_old, ratio)
        a = _axpy(y, k, h).detach().abs_()
        floor = 8 * torch.finfo(y.dtype).eps
        if self.rtol >= floor and self.atol >= floor:
            tol = a.mul_(self.rtol / h).add_(self.atol / h)
        else:
            tol = torch.maximum(self.atol + self.rtol * a, floor * (1 + a)) / h
        tm = t + h / 2
        done = ~rows.alive[:, None] if rows.any_stopped else None
        for _ in range(self.options["max_iters"]):
            k_new = func(tm, _axpy(y, k, h / 2))
            close = (k_new - k).detach().abs_() <= tol
            if done is None:  # no row has converged yet: all rows take the new iterate
                k = k_new
                if bool(close.all()):
                    break
                ok = close.all(-1, keepdim=True)
                if bool(ok.any()):
                    done = ok
                continue
            k = torch.where(done, k, k_new)
            done = done | close.all(-1, keepdim=True)
            if bool(done.all()):
                break
        else:
            failed = ~done[:, 0] if done is not None else torch.ones_like(rows.alive)
            t_fail = float((t + h / 2).max())
            rows.stop(failed & torch.isfinite(k_new).all(-1), Status.NOT_CONVERGED, t_fail)
            rows.stop(failed, Status.DIVERGED, t_fail)
            k = torch.where(failed[:, None], 0.0, k)
        return _axpy(y, k, h), (k, h, cache[0], (h_prev + h) / 2)


def _axpy(y: Tensor, x: Tensor, a: float | Tensor) -> Tensor:
    """``y + a x`` for a float ``a`` or a per-row ``a (B, 1)``."""
    return y + a * x if isinstance(a, Tensor) else torch.add(y, x, alpha=a)


@dataclass(frozen=True)
class _ButcherTableau:
    """An explicit Runge-Kutta method with an embedded error estimate (torchdiffeq's).

    Stage ``i``: ``k_i = f(t + alpha_i h, y + h Σ_j beta_ij k_j)`` (``alpha_0 = 0``,
    ``k_0 = f(t, y)``); the step ``y1 = y + h Σ_i c_sol_i k_i``, its error estimate
    ``h Σ_i c_error_i k_i`` (higher minus lower order) and the dense-output midpoint
    ``y(t + h/2) ≈ y + h Σ_i c_mid_i k_i``.
    """

    alpha: tuple[float, ...]
    beta: tuple[tuple[float, ...], ...]
    c_sol: tuple[float, ...]
    c_error: tuple[float, ...]
    c_mid: tuple[float, ...]


_DOPRI5 = _ButcherTableau(
    alpha=(0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0),
    beta=(
        (1 / 5,),
        (3 / 40, 9 / 40),
        (44 / 45, -56 / 15, 32 / 9),
        (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
        (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
        (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
    ),
    c_sol=(35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0),
    c_error=(
        35 / 384 - 1951 / 21600,
        0.0,
        500 / 1113 - 22642 / 50085,
        125 / 192 - 451 / 720,
        -2187 / 6784 + 12231 / 42400,
        11 / 84 - 649 / 6300,
        -1 / 60,
    ),
    c_mid=(
        6025192743 / 30085553152 / 2,
        0.0,
        51252292925 / 65400821598 / 2,
        -2691868925 / 45128329728 / 2,
        187940372067 / 1594534317056 / 2,
        -1776094331 / 19743644256 / 2,
        11237099 / 235043384 / 2,
    ),
)

# Dense output: ``y(t0 + x h) ≈ Σ_v w_v(x) v`` for ``v = (y0, y1, y_mid, h f0, h f1)``,
# ``w = (1, x, x², x³, x⁴) @ _DENSE``: the quartic with ``p(0) = y0``, ``p(1) = y1``,
# ``p(1/2) = y_mid``, ``p'(0) = h f0``, ``p'(1) = h f1`` (torchdiffeq's ``_interp_fit``).
_DENSE = (
    (1.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 1.0, 0.0),
    (-11.0, -5.0, 16.0, -4.0, 1.0),
    (18.0, 14.0, -32.0, 5.0, -3.0),
    (-8.0, -8.0, 16.0, -2.0, 2.0),
)


class _Active(NamedTuple):
    """The ``A`` rows of a :class:`Dopri5` run still integrating: their rows ``idx`` in
    the batch; state ``y`` and ``f = func(t, y)``, ``(A, D)``; time ``t`` and next step
    ``h`` (float64); ``nxt``, the index of the next output time; ``last``, whether the
    next step ends at the final time; ``stiff`` and ``still``, how many checked steps
    in a row were stiff or left the state unchanged; all but ``y``, ``f`` ``(A,)``."""

    idx: Tensor
    y: Tensor
    f: Tensor
    t: Tensor
    h: Tensor
    nxt: Tensor
    last: Tensor
    stiff: Tensor
    still: Tensor


class Dopri5(_Solver):
    """Dormand-Prince 5(4) with error control per trajectory and dense output.

    Every row ``b`` has its own time ``t_b`` and step ``h_b``. A step is accepted if
    ``‖err / (atol + rtol max(|y0|, |y1|))‖_rms <= 1`` over the row's ``D`` entries;
    the next step is ``h · clamp(0.9 err^(-1/5), 0.2, 10)`` (a rejected or
    non-finite step shrinks ``h``), clipped only to the final time. The initial step
    follows Hairer's heuristic, row by row. Outputs at ``t`` come from the quartic
    interpolant through ``y0``, ``y1``, the Shampine midpoint and ``f0``, ``f1``.
    ``func`` is evaluated only on unfinished rows, with ``t`` of shape ``(A, 1)``.
    Times and step sizes are kept in float64 whatever ``y0``'s dtype; no gradient
    flows through the step-size control.

    Options: ``max_steps`` attempted steps per row (default 100000), ``first_step``
    for all rows instead of the heuristic, ``stiff_steps`` (default 500; ``0``: off).
    A row stops (:class:`Status`) on a step-size underflow (a singularity, a field
    returning NaN), a state beyond the blow-up limit, 8 checks in a row (one every 16
    steps) whose accepted step left the state unchanged (a tolerance below the
    dtype's resolution), Hairer's stiffness test ``h λ > 3.25`` on about
    ``stiff_steps`` consecutive accepted steps, or ``max_steps``. Tolerances far below
    the dtype's resolution raise ValueError before any step.
    """

    order = 5
    defaults = {"max_steps": 100_000, "first_step": None, "stiff_steps": 500}
    tableau = _DOPRI5

    def __init__(self, rtol, atol, step_size, options):
        if step_size is not None:
            raise ValueError(
                "dopri5 is adaptive and takes no step_size; control it with rtol/atol "
                "(or options={'first_step': h0})"
            )
        super().__init__(rtol, atol, step_size, options)
        self._tables: dict[tuple, dict[str, Any]] = {}

    @property
    def _stiff_limit(self) -> float:
        """Checked steps in a row that make a row stiff (option ``stiff_steps``)."""
        return math.ceil(self.options["stiff_steps"] / _CHECK_EVERY) or math.inf

    def _coefficients(self, dtype: torch.dtype, tdtype: torch.dtype, device) -> dict[str, Any]:
        """The tableau (``alpha`` in ``tdtype``) and :data:`_DENSE` as tensors, cached per
        ``odeint`` call (inference-mode tensors must not reach a later autograd call)."""
        key = (dtype, tdtype, device)
        if key not in self._tables:
            tab, kw = self.tableau, {"dtype": dtype, "device": device}
            self._tables[key] = {
                "alpha": torch.tensor(tab.alpha, dtype=tdtype, device=device),
                "beta": [torch.tensor(row, **kw) for row in tab.beta],
                **{k: torch.tensor(getattr(tab, k), **kw) for k in ("c_sol", "c_error", "c_mid")},
                "dense": torch.tensor(_DENSE, **kw),
            }
        return self._tables[key]

    def step(
        self, func: Field, t: Tensor, y: Tensor, f: Tensor, h: Tensor, stiffness: bool = False
    ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
        """One attempted step of every row from ``t, h (A,)`` (float64), ``y (A, D)``
        and ``f = func(t, y)``: ``y1``, ``f1 = func(t + h, y1)``, the error estimate and
        the dense-output midpoint ``y(t + h/2)``, each ``(A, D)``, and (if ``stiffness``)
        Hairer's stiffness estimate ``h λ = h ‖k7 − k6‖ / ‖y7 − y6‖`` ``(A,)``.
        """
        coef = self._coefficients(y.dtype, t.dtype, y.device)
        tc = torch.addcmul(t[:, None], h[:, None], coef["alpha"]).to(y.dtype)
        hy = h.to(y.dtype)[:, None]
        ks = [f]
        for i, beta in enumerate(coef["beta"], start=1):
            y_stage = y + hy * (torch.stack(ks, -1) @ beta)
            ks.append(func(tc[:, i : i + 1], y_stage))
            if i == 5:
                y6 = y_stage
        k = torch.stack(ks, -1)
        y1 = y + hy * (k @ coef["c_sol"])
        h_lambda = None
        if stiffness:  # stages 6 and 7 share the time t + h
            with torch.no_grad():
                h_lambda = h * (_rms(ks[6] - ks[5]) / _rms(y1 - y6)).to(h.dtype)
        return y1, ks[-1], hy * (k @ coef["c_error"]), y + hy * (k @ coef["c_mid"]), h_lambda

    def integrate(self, func, y0, t, blowup=1e6, sign=1.0):
        B, D = y0.shape
        eps = torch.finfo(y0.dtype).eps
        if self.rtol < eps / 10 and self.atol < eps / 10 * float(y0.abs().max()):
            raise ValueError(
                f"dopri5: rtol = {self.rtol:g}, atol = {self.atol:g} are below {y0.dtype}'s "
                f"resolution (eps = {eps:.2g}): no step can meet them. Loosen them or "
                "integrate in float64."
            )
        tt = t.detach().to(torch.float64 if y0.device.type != "mps" else y0.dtype)
        rows, span = _Rows(y0, blowup, sign), float(tt[-1] - tt[0])
        run = self._start(func, y0, tt)
        outs = [(run.idx, y0)]
        for n_step in range(self.options["max_steps"]):
            run, out = self._attempt(func, run, tt, span, rows, n_step % _CHECK_EVERY == 0)
            outs.extend(out)
            if run is None:
                break
        else:
            rows.stop(torch.ones_like(run.idx, dtype=torch.bool), Status.MAX_STEPS, run.t, run.idx)
        idx, val = (torch.cat(x) for x in zip(*outs))
        out = y0.new_full((t.shape[0] * B, D), math.nan).index_put((idx,), val)
        return Solution(out.reshape(t.shape[0], B, D), rows.status, rows.t_stop)

    def _start(self, func: Field, y0: Tensor, tt: Tensor) -> _Active:
        """All rows at ``tt[0]``, with Hairer's first step (or option ``first_step``)."""
        B, dev = y0.shape[0], y0.device
        t0 = tt[0].expand(B).clone()
        f0 = func(t0.to(y0.dtype)[:, None], y0)
        if self.options["first_step"] is None:
            h = self._initial_step(func, t0, y0, f0)
        else:
            h = torch.full((B,), abs(float(self.options["first_step"])), dtype=tt.dtype, device=dev)
        h, last = _clip_to_end(t0, h, tt[-1])
        zero = torch.zeros(B, dtype=torch.long, device=dev)
        one = torch.ones_like(zero)
        return _Active(torch.arange(B, device=dev), y0, f0, t0, h, one, last, zero, zero)

    def _attempt(self, func, run, tt, span, rows, check) -> tuple[_Active | None, list]:
        """One attempted step of the rows ``run`` towards the output times ``tt (T,)``:
        accepted where :func:`_error_ratio` ``<= 1``, next step :func:`_optimal_step`,
        failing rows stopped (:meth:`_stop`; ``check``: one step in ``_CHECK_EVERY``).
        Returns the rows still integrating (``None``: none) and a list of the outputs
        passed (:meth:`_dense_output`; empty if none)."""
        y1, f1, err, mid, h_lambda = self.step(func, run.t, run.y, run.f, run.h, stiffness=check)
        with torch.no_grad():  # no gradient flows through the step-size control
            ratio = _error_ratio(err, run.y, y1, self.rtol, self.atol, run.t.dtype)
            acc = ratio <= 1
            blown, stiff, still = _watch(run, y1, h_lambda, acc, rows.limit, check)
        t_end = tt[-1]
        t1 = torch.where(acc, torch.where(run.last, t_end, run.t + run.h), run.t)
        h1, last = _clip_to_end(t1, _optimal_step(run.h, ratio), t_end)
        a2 = acc[:, None]
        y, f = torch.where(a2, y1, run.y), torch.where(a2, f1, run.f)
        upto = torch.searchsorted(tt, t1, right=True)
        new = _Active(run.idx, y, f, t1, h1, upto, last, stiff, still)
        done = acc & run.last & ~blown
        stopped = self._stop(rows, new, run.t, blown, ratio, done, span, check)
        counts = new.nxt - run.nxt
        if rows.any_stopped:
            counts = torch.where(blown, 0, counts)
        n_done, n_out = torch.stack([done.sum(), counts.sum()]).tolist()
        out = [self._dense_output(run, y1, f1, mid, tt, counts, n_out, rows)] if n_out else []
        n_finished = n_done + int(stopped.sum()) if rows.any_stopped else n_done
        if n_finished == run.idx.shape[0]:
            return None, out
        if n_finished:
            keep = ~(done | stopped)
            new = _Active(*(v[keep] for v in new))
        return new, out

    def _stop(self, rows, new, t0, blown, ratio, done, span, check) -> Tensor:
        """Stop detection after a step from ``t0 (A,)`` to ``new``: a row not ``done``
        stops in ``rows`` with the first reason that holds: DIVERGED (``blown``, or an
        underflow after a non-finite error), STALLED (``_STALL_CHECKS`` checks), STIFF
        (option ``stiff_steps``), STEP_UNDERFLOW (``h < 1e-14 max(|t|, span)``); at
        ``t0`` if blown, else at ``new.t``. Returns the stopped rows ``(A,)`` (bool)."""
        under = (new.h < 1e-14 * new.t.abs().clamp(min=span)) & ~done | blown
        if check:
            under = under | (new.still >= _STALL_CHECKS) | (new.stiff >= self._stiff_limit)
        stopped = torch.zeros_like(done)
        if not bool(under.any()):
            return stopped
        at = torch.where(blown, t0, new.t)
        for mask, code in (
            (blown | (under & ~torch.isfinite(ratio)), Status.DIVERGED),
            (new.still >= _STALL_CHECKS, Status.STALLED),
            (new.stiff >= self._stiff_limit, Status.STIFF),
            (under, Status.STEP_UNDERFLOW),
        ):
            mask = mask & ~stopped & ~done
            rows.stop(mask, code, at, new.idx)
            stopped = stopped | mask
        return stopped

    def _dense_output(self, run, y1, f1, mid, tt, counts, n_out, rows) -> tuple[Tensor, Tensor]:
        """The ``n_out`` outputs of the steps from ``run`` to ``y1``: row ``a`` passed the
        ``counts[a]`` output times from ``tt[run.nxt[a]]``, each ``Σ_v w_v(x) v`` at
        ``x = (t_j − t) / h`` (:data:`_DENSE`; torchdiffeq's ``_interp_evaluate``).
        Returns their indices ``j B + b`` into the ``(T B, D)`` output and the states
        ``(n_out, D)``."""
        dense = self._coefficients(y1.dtype, tt.dtype, y1.device)["dense"]
        start = counts.cumsum(0) - counts
        owner = torch.bincount(start, minlength=n_out + 1)[:n_out].cumsum(0) - 1
        j = torch.arange(n_out, device=y1.device) + (run.nxt - start)[owner]
        x = ((tt[j] - run.t[owner]) / run.h[owner]).to(y1.dtype)
        powers = x[:, None].expand(n_out, 4).cumprod(1)[:, :, None]
        w = dense[0] + (powers * dense[1:]).sum(1)
        hy = run.h.to(y1.dtype)[:, None]
        v = torch.stack([run.y, y1, mid, hy * run.f, hy * f1], -1)
        return j * rows.alive.shape[0] + run.idx[owner], (v[owner] * w[:, None]).sum(-1)

    def _initial_step(self, func: Field, t0: Tensor, y0: Tensor, f0: Tensor) -> Tensor:
        """Hairer's starting step, per row: ``(B,)`` float64 from ``t0 (B,)``, ``y0``, ``f0``.

        With ``s = atol + rtol |y0|``, ``d0 = ‖y0/s‖``, ``d1 = ‖f0/s‖``: ``h0 = 0.01 d0/d1``,
        one Euler step of ``h0`` gives ``d2 = ‖(f(y0 + h0 f0) - f0)/s‖ / h0``, and
        ``h = min(100 h0, (0.01 / max(d1, d2))^(1/5))`` (RMS norms).
        """
        with torch.no_grad():
            scale = (self.atol + self.rtol * y0.abs()).clamp_min(torch.finfo(y0.dtype).tiny)
            d0, d1 = _rms(y0 / scale).to(t0.dtype), _rms(f0 / scale).to(t0.dtype)
            h0 = torch.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * d0 / d1)
            h0 = torch.nan_to_num(h0, nan=1e-6, posinf=1e-6)
            y1 = y0 + h0.to(y0.dtype)[:, None] * f0
            f1 = func((t0 + h0).to(y0.dtype)[:, None], y1)
            d2 = _rms((f1 - f0) / scale).to(t0.dtype) / h0
            dm = torch.maximum(d1, d2)
            h1 = torch.where(dm <= 1e-15, torch.clamp(h0 * 1e-3, min=1e-6), (0.01 / dm) ** 0.2)
            h = torch.minimum(100 * h0, h1)
            return torch.where(torch.isfinite(h) & (h > 0), h, 1e-6)


def _error_ratio(err, y, y1, rtol: float, atol: float, tdtype: torch.dtype) -> Tensor:
    """``‖err / (atol + rtol max(|y|, |y1|))‖_rms`` per row, ``(A, D) -> (A,)`` in
    ``tdtype``, NaN read as ``inf``: a step is accepted if it is ``<= 1``."""
    tol = (atol + rtol * torch.maximum(y.abs(), y1.abs())).clamp_min(torch.finfo(y.dtype).tiny)
    return _rms(err / tol).to(tdtype).nan_to_num(nan=math.inf)


def _optimal_step(h: Tensor, ratio: Tensor) -> Tensor:
    """The next step after an error ratio, ``h · clamp(0.9 ratio^(-1/5), 0.2, 10)``,
    ``(A,)`` (torchdiffeq's ``_optimal_step_size``): a rejected step shrinks ``h``."""
    return h * (0.9 * ratio.pow(-0.2)).clamp(0.2, 10.0)


def _clip_to_end(t: Tensor, h: Tensor, t_end: Tensor) -> tuple[Tensor, Tensor]:
    """``(h, last)``, ``(A,)`` each: a step that would end within ``1.01 h`` of
    ``t_end`` or beyond it ends at ``t_end`` and is the row's ``last``."""
    last = t + 1.01 * h >= t_end
    return torch.where(last, t_end - t, h), last


def _watch(run: _Active, y1, h_lambda, acc, limit, check: bool) -> tuple[Tensor, Tensor, Tensor]:
    """``(blown, stiff, still)``, ``(A,)`` each, after the accepted steps ``acc`` from
    ``run`` to ``y1``: ``blown``, ``y1`` non-finite (on a ``check`` step: ``|y1|∞``
    beyond the row's ``limit (B,)``); on ``check`` steps, the runs of ``run.stiff``
    (``h λ > 3.25``) and ``run.still`` (``|y1 − y| <= eps |y|`` with ``f ≠ 0``) grow
    by an accepted step that has the property and restart at 0 on one that has not."""
    if not check:
        return acc & ~torch.isfinite(y1).all(-1), run.stiff, run.still
    eps = torch.finfo(y1.dtype).eps
    still = ((y1 - run.y).abs() <= eps * run.y.abs()).all(-1) & (run.f != 0).any(-1)
    stiff = torch.where(acc, (run.stiff + 1) * (h_lambda > 3.25), run.stiff)
    still = torch.where(acc, (run.still + 1) * still, run.still)
    return acc & ~(y1.abs().amax(-1) <= limit[run.idx]), stiff, still


def _rms(x: Tensor) -> Tensor:
    """Root mean square over the last axis: ``(B, D) -> (B,)``."""
    return torch.linalg.vector_norm(x, dim=-1) / math.sqrt(x.shape[-1])


METHODS: dict[str, type[_Solver]] = {
    "euler": Euler,
    "rk4": RK4,
    "leapfrog": Leapfrog,
    "implicit_midpoint": ImplicitMidpoint,
    "dopri5": Dopri5,
}


#: ``(rtol, atol)`` of :func:`odeint` when not given, by ``y0``'s dtype (others: float32's)
DEFAULT_TOLERANCES: dict[torch.dtype, tuple[float, float]] = {
    torch.float64: (1e-7, 1e-9),
    torch.float32: (1e-5, 1e-6),
}


def odeint(
    func: Field,
    y0: Tensor,
    t: Tensor,
    method: str = "dopri5",
    rtol: float | None = None,
    atol: float | None = None,
    step_size: float | None = None,
    options: dict[str, Any] | None = None,
    return_status: bool = False,
    blowup: float = 1e6,
) -> Tensor | Solution:
    """Integrate ``dy/dt = func(t, y)`` from ``y(t[0]) = y0`` and return ``y(t)``.

    Args:
        func: ``func(t, y)``, ``(batch, dim) -> (batch, dim)``, rows independent (solvers
            may pass a subset); ``t`` has ``y``'s dtype and broadcasts against ``y``: 0-d
            for fixed-step methods, ``(rows, 1)`` for ``dopri5``.
        y0: initial states ``(batch, dim)`` or ``(dim,)``, at ``t[0]``.
        t: ``(T,)`` finite, strictly monotone output times, cast to ``y0``'s dtype.
        method: a key of :data:`METHODS`.
        rtol, atol: tolerances of ``dopri5`` and of the ``implicit_midpoint`` iteration;
            ``None``: :data:`DEFAULT_TOLERANCES` of ``y0``'s dtype (float64: 1e-7, 1e-9;
            float32: 1e-5, 1e-6, which float32 arithmetic can meet; at 1e-7 the
            spring over t ∈ [0, 20] takes 2.6× the field calls).
        step_size: fixed-step methods only (module docstring); ``None``: one step per
            output interval.
        options: method-specific options (see each class in :data:`METHODS`).
        return_status: return a :class:`Solution` (states, per-row status and stop
            time) instead of raising when a row stops.
        blowup: a row whose ``|y|∞`` exceeds ``blowup · (1 + |y0|∞)`` has diverged.

    Returns:
        ``(T, batch, dim)`` (``(T, dim)`` for 1-D ``y0``), ``y0``'s dtype and device,
        ``out[0] == y0``; a :class:`Solution` of those if ``return_status``.

    Raises:
        ValueError: bad method, option, tolerance, shape or ``t``, a ``step_size`` for
            ``dopri5``, or a field whose output is not shaped like its input.
        RuntimeError: a row stopped (:class:`Status`) and ``return_status`` is false.
    """
    solver, t = _prepare(method, y0, t, rtol, atol, step_size, options, blowup)
    y = y0[None] if y0.ndim == 1 else y0
    if t.shape[0] == 1:
        B = y.shape[0]
        sol = Solution(y[None], torch.zeros(B, dtype=torch.long), torch.full((B,), math.nan))
    else:
        field, times, sign = _increasing(func, t)
        field = _checked(field)
        integrate = partial(solver.integrate, field, t=times, blowup=blowup, sign=sign)
        sol = _finite_rows(integrate, y, t.shape[0], float(t[0]))
    if y0.ndim == 1:
        sol = Solution(sol.y[:, 0], sol.status[0], sol.t_stop[0])
    if return_status:
        return sol
    if not bool(sol.ok.all()):
        raise RuntimeError(sol.describe(method))
    return sol.y


def _prepare(method, y0, t, rtol, atol, step_size, options, blowup) -> tuple[_Solver, Tensor]:
    """The solver of :func:`odeint`'s checked arguments and ``t (T,)`` in ``y0``'s dtype
    and device; ``None`` tolerances: :data:`DEFAULT_TOLERANCES` of ``y0``'s dtype."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; valid methods: {sorted(METHODS)}")
    if not (isinstance(y0, Tensor) and y0.is_floating_point() and y0.ndim in (1, 2)):
        raise ValueError("y0 must be a floating-point tensor of shape (batch, dim) or (dim,)")
    default_rtol, default_atol = DEFAULT_TOLERANCES.get(y0.dtype, DEFAULT_TOLERANCES[torch.float32])
    rtol = default_rtol if rtol is None else rtol
    atol = default_atol if atol is None else atol
    for name, value in (("rtol", rtol), ("atol", atol)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {value}")
    if step_size is not None and not (math.isfinite(step_size) and step_size > 0):
        raise ValueError(f"step_size must be finite and > 0, got {step_size}")
    if not blowup > 0:
        raise ValueError(f"blowup must be > 0, got {blowup}")
    solver = METHODS[method](rtol, atol, step_size, options)
    t = torch.as_tensor(t).to(dtype=y0.dtype, device=y0.device)
    if t.ndim != 1 or t.shape[0] == 0:
        raise ValueError(f"t must be a non-empty 1-D tensor, got shape {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"t must be finite, got {t.tolist()[:8]}")
    return solver, t


def _increasing(func: Field, t: Tensor) -> tuple[Field, Tensor, float]:
    """``(func, t, 1.0)`` for increasing ``t``; for decreasing ``t`` the substitution
    ``s = -t``: ``(dy/ds = -func(-s, y), -t, -1.0)``."""
    dt = t[1:] - t[:-1]
    if bool((dt < 0).all()):
        return (lambda s, y: -func(-s, y)), -t, -1.0
    if bool((dt > 0).all()):
        return func, t, 1.0
    raise ValueError("t must be strictly increasing or strictly decreasing")


def _finite_rows(integrate, y0: Tensor, n_times: int, t0: float) -> Solution:
    """``integrate`` (a solver's, on all but ``y0``) of the rows of ``y0 (B, D)`` that
    start finite; the others stop at once with :attr:`Status.DIVERGED` at ``t0`` (their
    output: the start, then NaN), whatever the field returns there (a tanh field is
    finite at ``inf``)."""
    finite = torch.isfinite(y0.detach()).all(-1)
    if bool(finite.all()):
        return integrate(y0)
    B = y0.shape[0]
    status = torch.full((B,), int(Status.DIVERGED), dtype=torch.long, device=y0.device)
    t_stop = torch.full((B,), t0, dtype=torch.float64, device=y0.device)
    y = torch.cat([y0[None], y0.new_full((n_times - 1, *y0.shape), math.nan)])
    if bool(finite.any()):
        sol = integrate(y0[finite])
        rows = finite.nonzero().flatten()
        y = y.transpose(0, 1).index_put((rows,), sol.y.transpose(0, 1)).transpose(0, 1)
        status[rows], t_stop[rows] = sol.status, sol.t_stop
    return Solution(y, status, t_stop)


#: the fixed-step methods :func:`odeint_windows` accepts
WINDOW_METHODS = ("euler", "rk4", "leapfrog", "implicit_midpoint")


def odeint_windows(
    func: Field,
    y0: Tensor,
    t: Tensor,
    method: str = "rk4",
    substeps: int | Tensor = 1,
    rtol: float = 1e-7,
    atol: float = 1e-9,
    options: dict[str, Any] | None = None,
) -> Tensor:
    """Every row integrated to its own times in one batched, differentiable loop.

    Row ``b`` starts at ``y0[b]`` at ``t[b, 0]`` and is read at ``t[b, 1:]``; the
    interval ``[t[b, j], t[b, j+1]]`` is cut into ``n_j`` equal steps of the row's
    own size ``h_bj = (t[b, j+1] − t[b, j]) / n_j`` (``n_j`` = ``substeps``, or
    ``substeps[j]`` for a ``(K−1,)`` integer tensor), so uneven and per-row spacings
    land exactly on the samples. The loop runs over the ``Σ n_j`` steps, never over
    rows; gradients flow to ``y0`` and to ``func``'s parameters (discretise, then
    optimise), ``t`` is data. A zero-length interval is a step of size 0 (the state
    stays). No containment: a diverging row gives non-finite states; an
    ``implicit_midpoint`` iteration that fails to converge raises ``RuntimeError``.

    Args:
        func: ``func(t, y)``, ``(B, D) -> (B, D)``; ``t`` arrives as ``(B, 1)``.
        y0: ``(B, D)`` states at ``t[:, 0]``.
        t: ``(B, K)`` non-decreasing times per row, ``K >= 1``.
        method: one of :data:`WINDOW_METHODS` (a fixed-step class of :data:`METHODS`).
        substeps: steps per interval (``int >= 1``, or a ``(K−1,)`` tensor of them).
        rtol, atol, options: as :func:`odeint` (``implicit_midpoint``'s iteration;
            ``leapfrog``'s ``check_separable`` defaults to ``False`` here).

    Returns:
        ``(B, K, D)``, ``out[:, 0] == y0``.
    """
    if method not in WINDOW_METHODS:
        raise ValueError(f"odeint_windows: method must be one of {WINDOW_METHODS}, got {method!r}")
    if y0.ndim != 2 or t.ndim != 2 or t.shape[0] != y0.shape[0]:
        raise ValueError(
            f"odeint_windows needs y0 (B, D) and t (B, K), got {tuple(y0.shape)}, {tuple(t.shape)}"
        )
    n = torch.as_tensor(substeps).expand(t.shape[1] - 1).tolist()
    if any(k < 1 for k in n):
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    if method == "leapfrog":
        options = {"check_separable": False, **(options or {})}
    solver = METHODS[method](rtol, atol, None, options)
    rows = _Rows(y0, math.inf)
    t = t.to(y0.dtype)
    cache = solver._start(func, t[:, :1], y0)
    y, ys = y0, [y0]
    for j, steps in enumerate(n):
        h = (t[:, j + 1 : j + 2] - t[:, j : j + 1]) / steps
        for k in range(steps):
            y, cache = solver.step(func, t[:, j : j + 1] + k * h, y, h, cache, rows)
        ys.append(y)
    if rows.any_stopped:
        raise RuntimeError(Solution(y0, rows.status, rows.t_stop).describe(method))
    return torch.stack(ys, 1)


def _checked(func: Field) -> Field:
    """``func`` that checks, on its first call, that it returns a tensor shaped like ``y``
    (a ``(B, 1)`` field would broadcast to a wrong answer)."""
    first = True

    def checked(t: Tensor, y: Tensor) -> Tensor:
        nonlocal first
        out = func(t, y)
        if first:
            first = False
            shape = tuple(getattr(out, "shape", ()))
            if not isinstance(out, Tensor) or out.shape != y.shape:
                raise ValueError(
                    f"the vector field returned {type(out).__name__} of shape {shape} for "
                    f"states of shape {tuple(y.shape)}: it must return dy/dt shaped like y"
                )
        return out

    return checked


def scipy_fun(
    func: Field, shape: tuple[int, ...], dtype: torch.dtype | None = None
) -> Callable[[float, np.ndarray], np.ndarray]:
    """``fun(t: float, y_flat) -> dy_flat`` for ``scipy.integrate.solve_ivp``.

    Reshapes ``y_flat`` (float64) to ``shape`` (e.g. ``(batch, dim)``) in ``dtype``,
    evaluates ``func`` under ``torch.no_grad`` with a 0-d ``t`` and returns the
    flattened float64 result, so one ``solve_ivp`` call integrates the whole batch.
    ``dtype=None``: the dtype of the module ``func`` is a method of (e.g.
    ``model.vector_field`` of a float32 checkpoint), else float64.
    """
    if dtype is None:
        owner = getattr(func, "__self__", None)
        param = next(owner.parameters(), None) if isinstance(owner, torch.nn.Module) else None
        dtype = param.dtype if param is not None else torch.float64

    def fun(t: float, y_flat: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            y = torch.as_tensor(y_flat).to(dtype).reshape(shape)
            dy = func(torch.tensor(t, dtype=dtype), y)
            return dy.detach().reshape(-1).to("cpu", torch.float64).numpy()

    return fun


def scipy_odeint(
    func: Field,
    y0: Tensor,
    t: Tensor,
    method: str = "RK45",
    dtype: torch.dtype | None = None,
    **solve_ivp_kwargs: Any,
) -> Tensor:
    """``(T, batch, dim)`` float64 states at increasing ``t`` from ``y0 (batch, dim)``.

    One ``solve_ivp`` call (scipy ``method``, ``**solve_ivp_kwargs`` such as ``rtol``)
    on the flattened batch through :func:`scipy_fun`; RuntimeError if scipy fails.
    """
    from scipy.integrate import solve_ivp

    t_np = t.detach().to("cpu", torch.float64).numpy()
    sol = solve_ivp(
        scipy_fun(func, tuple(y0.shape), dtype),
        (float(t_np[0]), float(t_np[-1])),
        y0.detach().to("cpu", torch.float64).reshape(-1).numpy(),
        method=method,
        t_eval=t_np,
        **solve_ivp_kwargs,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp ({method}) failed: {sol.message}")
    return torch.from_numpy(sol.y.T.copy()).reshape(len(t_np), *y0.shape)
