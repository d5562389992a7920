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

Backward integration (decreasing ``t``) substitutes ``s = -t``, integrating
``dy/ds = -func(-s, y)`` forward. Gradients flow to ``y0`` and to parameters used by
``func`` (discretise-then-optimise); ``t`` is treated as data.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

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
    "odeint",
    "scipy_fun",
    "scipy_odeint",
]

Field = Callable[[Tensor, Tensor], Tensor]

_SEPARABILITY_TOL = 1e-6
_PROBE_ROWS = 64


class _Solver:
    """Base of all methods (arguments as :func:`odeint`; unknown options raise).

    ``order``: global error ``O(h^order)``; ``defaults``: the options and their
    defaults; ``sign``: ``-1.0`` while integrating backward (``s = -t``), for messages.
    """

    order: int = 0
    defaults: dict[str, Any] = {}
    sign: float = 1.0

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

    def integrate(self, func: Field, y0: Tensor, t: Tensor) -> Tensor:
        """States at ``t``: ``y0 (B, D)``, increasing ``t (T,)`` -> ``(T, B, D)``."""
        raise NotImplementedError


class _FixedStep(_Solver):
    """A fixed-step method: subclasses implement :meth:`step`."""

    def step(self, func: Field, t: Tensor, y: Tensor, h: float, cache: Any) -> tuple[Tensor, Any]:
        """One step ``y (B, D)`` at 0-d ``t`` -> ``(y(t + h), cache)``, ``h > 0``; ``cache``
        is what ``_start`` or the previous step returned (e.g. an FSAL evaluation)."""
        raise NotImplementedError

    def _start(self, func: Field, t0: Tensor, y0: Tensor) -> Any:
        return None

    def integrate(self, func: Field, y0: Tensor, t: Tensor) -> Tensor:
        ts = t.tolist()
        eps = torch.finfo(torch.float32).eps
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
                y, cache = self.step(func, tk, y, h, cache)
            ys.append(y)
        return torch.stack(ys)


class Euler(_FixedStep):
    """Explicit Euler: ``y1 = y0 + h f(t, y0)``."""

    order = 1

    def step(self, func, t, y, h, cache):
        return y + h * func(t, y), None


class RK4(_FixedStep):
    """Classic Runge-Kutta: ``y1 = y0 + h (k1 + 2 k2 + 2 k3 + k4) / 6``."""

    order = 4

    def step(self, func, t, y, h, cache):
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
                    stacklevel=4,
                )
        return f0[..., y0.shape[-1] // 2 :]

    def step(self, func, t, y, h, cache):
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
    Lipschitz constant): a step that does not converge in option ``max_iters``
    (default 50) iterations raises RuntimeError.
    """

    order = 2
    defaults = {"max_iters": 50}

    def _start(self, func, t0, y0):
        return func(t0, y0), 0.0, None, 0.0

    def step(self, func, t, y, h, cache):
        k, h_prev, k_old, spacing = cache
        if k_old is not None:
            k = k + (k - k_old) * ((h_prev + h) / (2 * spacing))
        a = (y + h * k).abs()
        tol = torch.maximum(self.atol + self.rtol * a, 8 * torch.finfo(y.dtype).eps * (1 + a)) / h
        tm = t + h / 2
        done = torch.zeros(y.shape[0], 1, dtype=torch.bool, device=y.device)
        for _ in range(self.options["max_iters"]):
            k_new = func(tm, y + (h / 2) * k)
            ok = ((k_new - k).abs() <= tol).all(-1, keepdim=True)
            k = torch.where(done, k, k_new)
            done = done | ok
            if bool(done.all()):
                return y + h * k, (k, h, cache[0], (h_prev + h) / 2)
        n_bad = int((~done).sum())
        finite = bool(torch.isfinite(k_new).all())
        raise RuntimeError(
            f"implicit_midpoint: the fixed-point iteration did not converge in "
            f"{self.options['max_iters']} iterations for {n_bad} of {y.shape[0]} rows at "
            f"t = {self.sign * float(t):.6g} with step size h = {h:.3g}"
            f"{'' if finite else ' (the iterates became non-finite)'}. "
            "It contracts only for h * Lipschitz(f) / 2 < 1: use a smaller step_size."
        )


# Dormand-Prince 5(4): nodes, stage rows, 5th-order weights (row 7), error weights
# (5th minus 4th order) and the weights of the midpoint used by the dense output.
_DP_C = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0)
_DP_A = (
    (1 / 5,),
    (3 / 40, 9 / 40),
    (44 / 45, -56 / 15, 32 / 9),
    (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
    (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
    (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
)
_DP_E = (
    35 / 384 - 1951 / 21600,
    0.0,
    500 / 1113 - 22642 / 50085,
    125 / 192 - 451 / 720,
    -2187 / 6784 + 12231 / 42400,
    11 / 84 - 649 / 6300,
    -1 / 60,
)
_DP_MID = (
    6025192743 / 30085553152 / 2,
    0.0,
    51252292925 / 65400821598 / 2,
    -2691868925 / 45128329728 / 2,
    187940372067 / 1594534317056 / 2,
    -1776094331 / 19743644256 / 2,
    11237099 / 235043384 / 2,
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
    for all rows instead of the heuristic. RuntimeError on too many steps or a step-size
    underflow (a field returning NaN, a singularity, ``rtol`` below the dtype's resolution).
    """

    order = 5
    defaults = {"max_steps": 100_000, "first_step": None}

    def __init__(self, rtol, atol, step_size, options):
        if step_size is not None:
            raise ValueError(
                "dopri5 is adaptive and takes no step_size; control it with rtol/atol "
                "(or options={'first_step': h0})"
            )
        super().__init__(rtol, atol, step_size, options)
        self._tables: dict[tuple, dict[str, Any]] = {}

    def _coefficients(self, dtype: torch.dtype, tdtype: torch.dtype, device) -> dict[str, Any]:
        # cached per odeint call: inference-mode tensors must not reach a later autograd call
        key = (dtype, tdtype, device)
        if key not in self._tables:

            def tensor(x, dt=dtype):
                return torch.tensor(x, dtype=dt, device=device)

            self._tables[key] = {
                "a": [tensor(row) for row in _DP_A],
                "b": tensor((*_DP_A[-1], 0.0)),
                "e": tensor(_DP_E),
                "mid": tensor(_DP_MID),
                "c": tensor(_DP_C, tdtype),
                "dense": tensor(_DENSE),
            }
        return self._tables[key]

    def step(
        self, func: Field, t: Tensor, y: Tensor, f: Tensor, h: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """One attempted step of every row from ``t, h (A,)`` (float64), ``y (A, D)``
        and ``f = func(t, y)``: ``y1``, ``f1 = func(t + h, y1)``, the error estimate and
        the dense-output midpoint ``y(t + h/2)``, each ``(A, D)``.
        """
        coef = self._coefficients(y.dtype, t.dtype, y.device)
        tc = torch.addcmul(t[:, None], h[:, None], coef["c"]).to(y.dtype)
        hy = h.to(y.dtype)[:, None]
        ks = [f]
        for i, a in enumerate(coef["a"], start=1):
            ks.append(func(tc[:, i : i + 1], y + hy * (torch.stack(ks, -1) @ a)))
        k = torch.stack(ks, -1)
        return y + hy * (k @ coef["b"]), ks[-1], hy * (k @ coef["e"]), y + hy * (k @ coef["mid"])

    def integrate(self, func: Field, y0: Tensor, t: Tensor) -> Tensor:
        B, D = y0.shape
        dtype, dev = y0.dtype, y0.device
        tdtype = torch.float64 if dev.type != "mps" else dtype
        coef = self._coefficients(dtype, tdtype, dev)
        tt = t.detach().to(tdtype)
        t_end, span = tt[-1], float(tt[-1] - tt[0])
        out_idx, out_val = [torch.arange(B, device=dev)], [y0]
        idx = torch.arange(B, device=dev)
        tc = tt[0].expand(B).clone()
        y = y0
        f = func(tc.to(dtype)[:, None], y)
        if self.options["first_step"] is None:
            h = self._initial_step(func, tc, y, f)
        else:
            h = torch.full((B,), abs(float(self.options["first_step"])), dtype=tdtype, device=dev)
        last = tc + 1.01 * h >= t_end
        h = torch.where(last, t_end - tc, h)
        nxt = torch.ones(B, dtype=torch.long, device=dev)
        tiny = torch.finfo(dtype).tiny
        for _ in range(self.options["max_steps"]):
            y1, f1, err, mid = self.step(func, tc, y, f, h)
            with torch.no_grad():
                tol = (self.atol + self.rtol * torch.maximum(y.abs(), y1.abs())).clamp_min(tiny)
                ratio = _rms(err / tol).to(tdtype).nan_to_num(nan=math.inf)
            acc = ratio <= 1
            t1 = torch.where(acc, torch.where(last, t_end, tc + h), tc)
            upto = torch.searchsorted(tt, t1, right=True)
            counts = upto - nxt
            h1 = h * (0.9 * ratio.pow(-0.2)).clamp(0.2, 10.0)
            done = acc & last
            last = t1 + 1.01 * h1 >= t_end
            h1 = torch.where(last, t_end - t1, h1)
            bad = (h1 < 1e-14 * t1.abs().clamp(min=span)) & ~done
            n_bad, n_done, n_out = torch.stack([bad.sum(), done.sum(), counts.sum()]).tolist()
            if n_bad:
                self._fail("step size underflow", bad, idx, t1, h1, B, ~torch.isfinite(ratio))
            if n_out:
                start = counts.cumsum(0) - counts
                rows = torch.bincount(start, minlength=n_out + 1)[:n_out].cumsum(0) - 1
                j = torch.arange(n_out, device=dev) + (nxt - start)[rows]
                x = ((tt[j] - tc[rows]) / h[rows]).to(dtype)
                powers = x[:, None].expand(n_out, 4).cumprod(1)[:, :, None]
                w = coef["dense"][0] + (powers * coef["dense"][1:]).sum(1)
                hy = h.to(dtype)[:, None]
                v = torch.stack([y, y1, mid, hy * f, hy * f1], -1)
                out_val.append((v[rows] * w[:, None]).sum(-1))
                out_idx.append(j * B + idx[rows])
            a2 = acc[:, None]
            y, f, tc, h, nxt = torch.where(a2, y1, y), torch.where(a2, f1, f), t1, h1, upto
            if n_done == idx.shape[0]:
                break
            if n_done:
                keep = ~done
                idx, y, f, tc, h, nxt, last = (v[keep] for v in (idx, y, f, tc, h, nxt, last))
        else:
            everyone = torch.ones_like(idx, dtype=torch.bool)
            reason = f"more than max_steps = {self.options['max_steps']} steps"
            self._fail(reason, everyone, idx, tc, h, B, ~everyone)
        out = y0.new_zeros(t.shape[0] * B, D)
        out = out.index_put((torch.cat(out_idx),), torch.cat(out_val))
        return out.reshape(t.shape[0], B, D)

    def _fail(self, reason, rows: Tensor, idx, t, h, B: int, nonfinite: Tensor) -> None:
        n = int(rows.sum())
        t_r, h_r = (self.sign * t[rows]).tolist(), h[rows].tolist()
        hint = (
            " The field returned non-finite values on the last attempted step."
            if bool((nonfinite & rows).any())
            else " Check the field for singularities, or loosen rtol/atol (float32 cannot "
            "reach rtol much below 1e-6)."
        )
        raise RuntimeError(
            f"dopri5: {reason} for {n} of {B} trajectories (rows {idx[rows][:5].tolist()}"
            f"{'...' if n > 5 else ''}), stopped at t = {t_r[0]:.6g} with step size "
            f"{h_r[0]:.3g}.{hint}"
        )

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


def odeint(
    func: Field,
    y0: Tensor,
    t: Tensor,
    method: str = "dopri5",
    rtol: float = 1e-7,
    atol: float = 1e-9,
    step_size: float | None = None,
    options: dict[str, Any] | None = None,
) -> Tensor:
    """Integrate ``dy/dt = func(t, y)`` from ``y(t[0]) = y0`` and return ``y(t)``.

    Args:
        func: ``func(t, y)``, ``(batch, dim) -> (batch, dim)``, rows independent (solvers
            may pass a subset); ``t`` has ``y``'s dtype and broadcasts against ``y``: 0-d
            for fixed-step methods, ``(rows, 1)`` for ``dopri5``.
        y0: initial states ``(batch, dim)`` or ``(dim,)``, at ``t[0]``.
        t: ``(T,)`` strictly monotone output times, cast to ``y0``'s dtype.
        method: a key of :data:`METHODS`.
        rtol, atol: tolerances of ``dopri5`` and of the ``implicit_midpoint`` iteration.
        step_size: fixed-step methods only (module docstring); ``None``: one step per
            output interval.
        options: method-specific options (see each class in :data:`METHODS`).

    Returns:
        ``(T, batch, dim)`` (``(T, dim)`` for 1-D ``y0``), ``y0``'s dtype and device,
        ``out[0] == y0``.

    Raises:
        ValueError: bad method, option, shape or ``t``, or a ``step_size`` for ``dopri5``.
        RuntimeError: an implicit step does not converge or ``dopri5`` gives up.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; valid methods: {sorted(METHODS)}")
    if not (isinstance(y0, Tensor) and y0.is_floating_point() and y0.ndim in (1, 2)):
        raise ValueError("y0 must be a floating-point tensor of shape (batch, dim) or (dim,)")
    if rtol < 0 or atol < 0 or (step_size is not None and not step_size > 0):
        raise ValueError("rtol and atol must be >= 0 and step_size > 0")
    solver = METHODS[method](rtol, atol, step_size, options)
    t = torch.as_tensor(t).to(dtype=y0.dtype, device=y0.device)
    if t.ndim != 1 or t.shape[0] == 0:
        raise ValueError(f"t must be a non-empty 1-D tensor, got shape {tuple(t.shape)}")
    squeeze = y0.ndim == 1
    y = y0[None] if squeeze else y0
    if t.shape[0] == 1:
        out = y[None]
    else:
        dt = t[1:] - t[:-1]
        if bool((dt < 0).all()):
            solver.sign = -1.0
            out = solver.integrate(_reversed(func), y, -t)
        elif bool((dt > 0).all()):
            out = solver.integrate(func, y, t)
        else:
            raise ValueError("t must be strictly increasing or strictly decreasing")
    return out[:, 0] if squeeze else out


def _reversed(func: Field) -> Field:
    def neg(s: Tensor, y: Tensor) -> Tensor:
        return -func(-s, y)

    return neg


def scipy_fun(
    func: Field, shape: tuple[int, ...], dtype: torch.dtype = torch.float64
) -> Callable[[float, np.ndarray], np.ndarray]:
    """``fun(t: float, y_flat) -> dy_flat`` for ``scipy.integrate.solve_ivp``.

    Reshapes ``y_flat`` (float64) to ``shape`` (e.g. ``(batch, dim)``) in ``dtype``,
    evaluates ``func`` under ``torch.no_grad`` with a 0-d ``t`` and returns the
    flattened float64 result, so one ``solve_ivp`` call integrates the whole batch.
    """

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
    dtype: torch.dtype = torch.float64,
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
