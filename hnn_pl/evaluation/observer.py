"""The observer: a start ``(q₀, p₀)`` inferred from observed positions and a field.

A camera or an encoder records positions ``q`` only. To roll a field out from such a
recording, its start must be inferred: the state ``y₀ = (q₀, p₀)`` at the first
sample whose rollout under the field best matches the first ``M`` observed positions,

    ``y₀ = argmin_{(q₀, p₀)} Σ_j ‖q(t_j; q₀, p₀) − q_j‖²,  j = 0 … M−1``,

``q(t; ·)`` the first ``k`` coordinates of the field's rollout. From positions alone a
learned field's momenta are fixed only up to a canonical change that keeps ``q`` (a
scale ``p → c·p`` with ``H → c·H``; ``p → p + ∇F(q)``), so nothing here assumes a
relation between ``p`` and the velocity: the velocity is turned into a momentum
through the field's own ``q̇ = f(q, p)[:k]``. Four stages, every one batched over
trajectories and deterministic (no random draws):

1. **Fits** — polynomials in time (degree ``min(2, n − 1)``, least squares) through the
   first ``n`` positions, for each ``n`` of ``fits`` (default the first 3, 5 and all):
   a position ``q̂₀`` and a velocity ``v̂₀`` each.
2. **Newton** — for each fit, ``p`` with ``f(q̂₀, p)[:k] = v̂₀``, ``newton_iters``
   Newton steps from ``p = v̂₀`` with a central-difference Jacobian ``∂f_q/∂p (k, k)``
   (one field call of ``(2k + 1)`` rows per row and fit); the ``p`` of the smallest
   residual is kept. A row whose Jacobian is singular or non-finite at the start falls
   back to ``p = s·v̂₀``, ``s`` the median ``|p|/|v̂₀|`` of the rows Newton solved (1 if
   none).
3. **Coarse search** — the candidates ``(q̂₀, c·p)`` for every fit and every ``c`` of
   ``scales``, and a grid of momenta, each momentum clipped to ``|p_i| ≤ p_bound_i``
   when a bound is given, all rolled out in one call (one step per interval,
   a module's field in float32 — half the cost of float64: it only ranks them); each row
   keeps the one of the smallest sum of squares.
4. **Levenberg–Marquardt** on ``(q₀, p₀)`` over all ``M`` positions: the residual's
   Jacobian by forward differences, the trial point and its ``2k`` perturbations rolled
   out in one call of ``(2k + 1)`` rows per row; step ``(JᵀJ + λ·diag JᵀJ)⁻¹ Jᵀr``;
   per-row damping ``λ`` (Nielsen's update from the gain ratio) and acceptance (the
   trial must lower the row's sum of squares). A row stops once an accepted step
   lowers its cost, or the Gauss–Newton model predicts its step would, by less than
   ``max(1e-5, 16ε)`` of it — with ``C`` the cost, ``C/(Mk − 2k)`` estimates the
   noise's variance, and a step whose decrease is ``1e-5·C`` is about
   ``√(1e-5·(Mk − 2k)) ≈ 1 %`` (15 samples, ``k = 1``) of the start's standard
   error — or its step is below ``xtol·(1 + |y₀|)``,
   ``xtol = 0.01·√ε`` (``ε`` of the dtype the field runs in: a float32 field's rollouts
   are only that exact); the others continue, up to ``iters`` iterations. With a
   ``p_bound``, each trial's momenta are clipped to it (a projected step).

A learned field is trusted only where it was trained: on noisy positions a start far
outside the training momenta can fit the first samples marginally better than the
truth and then roll out into a region the field never saw (a trained spring HNN's
observer picked ``|p| ≈ 6–8`` where training reached 3, position MSE 0.90 where a
bounded search gives 0.09). :func:`training_momentum_bound` gives ``p_bound`` for a
trained model: :data:`MOMENTUM_BOUND` times the largest ``|p_i|`` it was trained on. Forward
   differences of step ``√ε·(1 + |y₀ᵢ|)`` bias the minimiser of noisy data by about
   ``√ε`` relative (1e-8 in float64), far below what the noise leaves undetermined.

Rollouts are :func:`~hnn_pl.integrate.odeint_windows` (``method``, ``substeps`` steps
per interval between samples, each row on its own times, so uneven spacing is exact;
one by default, as the trajectory recipes integrate their windows: RK4 at the pendulum's
``Δt ≈ 1/15`` leaves 1e-5 on an exact start, far below any noise).
States are float64. A model's field is evaluated as the evaluation's rollouts do
(:func:`~hnn_pl.evaluation.base.integrate_field`): a float64 copy by default, the same
function as a float32 model's without its rounding, or in its own dtype with
``dtype="model"`` (float64 states are cast, as :meth:`RecipeModel.in_own_dtype` does);
finite-difference steps and tolerances follow the dtype used. No gradient through the
field is needed, nor recorded: everything runs under ``torch.no_grad``.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.evaluation.base import in_dtype
from hnn_pl.integrate import odeint_windows
from hnn_pl.safe_io import torch_load

F64 = torch.float64
#: the observed positions a start is inferred from when the data observe positions alone
#: (the first second of the paper's spring and pendulum draws)
POSITION_SAMPLES = 15
#: LM stops for a row whose step lowers its cost, or would by the Gauss–Newton model, by
#: less than this fraction (or 16·ε of the field's dtype, where that is larger: a
#: float32 field's cost is that noisy): about 1 % of the start's standard error
FTOL = 1e-5
_LAMBDA0, _LAMBDA_MAX = 1e-3, 1e12
#: a trained model's observer searches momenta up to this factor of the largest ``|p_i|``
#: it was trained on (:func:`training_momentum_bound`)
MOMENTUM_BOUND = 1.5


class ObserverStatus(enum.IntEnum):
    """Why :func:`observe` ended for a row."""

    OK = 0  # Levenberg–Marquardt converged
    MAX_ITERS = 1  # iterations ran out first; y0 is the best point found
    BAD_INPUT = 2  # a non-finite or decreasing time, or a non-finite position: y0 is NaN
    DIVERGED = 3  # every candidate's rollout was non-finite: y0 is the fit's (q̂₀, p)


@dataclass
class Observation:
    """What :func:`observe` returns.

    ``y0 (B, 2k)`` float64: the inferred starts at each row's first time; ``rms (B,)``:
    ``sqrt(mean_{j,i} (q_i(t_j) − q_ij)²)``, the root mean square position residual of
    the rollout from ``y0`` at the ``M`` samples (NaN for a bad row); ``status (B,)``:
    :class:`ObserverStatus` codes; ``iterations``: LM iterations run.
    """

    y0: Tensor
    rms: Tensor
    status: Tensor
    iterations: int

    @property
    def ok(self) -> Tensor:
        """``(B,)`` bool: rows whose start is usable (``OK`` or ``MAX_ITERS``)."""
        return self.status <= ObserverStatus.MAX_ITERS


def float64_field(
    field: Any, dtype: str | torch.dtype | None = "float64"
) -> tuple[Callable[[Tensor | None, Tensor], Tensor], float]:
    """``f(t, y) = field.vector_field(t, y)`` without gradients, float64 states
    ``(N, 2k)`` in and out, and the machine epsilon of the dtype it computes in.

    ``field``: a model (its ``.field`` is used, as the rollouts do), a model's ``.field``,
    or anything else with ``vector_field`` (a system). A module is evaluated as
    :func:`~hnn_pl.evaluation.base.integrate_field` does: in ``dtype`` (a copy when its
    parameters are in another; the default float64 evaluates a float32 model's exact
    function without its rounding), or in its own with ``"model"``/``None``. A system
    computes in its input's dtype, float64."""
    module = getattr(field, "field", field) if isinstance(field, nn.Module) else field
    run = F64
    if isinstance(module, nn.Module):
        module = in_dtype(module, dtype)
        param = next(module.parameters(), None)
        run = param.dtype if param is not None else F64

    def f(t: Tensor | None, y: Tensor) -> Tensor:
        t = t.to(run) if isinstance(t, Tensor) else t
        with torch.no_grad():
            return module.vector_field(t, y.to(run)).to(F64)

    return f, torch.finfo(run).eps


def ranking_field(
    field: Any, dtype: str | torch.dtype | None = "float64"
) -> Callable[[Tensor | None, Tensor], Tensor] | None:
    """The coarse search's field: a module's (a model's, or its ``.field``) function as
    :func:`float64_field` evaluates it in ``dtype``, but computed in float32 (a copy
    unless ``dtype`` is the module's own and that is float32), float64 states in and
    out: ranking candidates does not need float64, and float32 costs half. ``None`` for
    anything else (a system: evaluated as is)."""
    module = getattr(field, "field", field) if isinstance(field, nn.Module) else field
    if not isinstance(module, nn.Module):
        return None
    return float64_field(in_dtype(module, dtype), torch.float32)[0]


def fit_position_velocity(t: Tensor, q: Tensor, n: int) -> tuple[Tensor, Tensor]:
    """Least-squares polynomial of degree ``min(2, n − 1)`` in ``t − t₀`` through the first
    ``n`` samples of each row: ``t (B, M)``, ``q (B, M, k)`` -> its value ``q̂₀`` and slope
    ``v̂₀`` at ``t₀ = t[:, 0]``, each ``(B, k)``. Time is scaled by each row's span (a
    zero span gives ``v̂₀ = 0``); the pseudo-inverse handles repeated times."""
    tc = t[:, :n] - t[:, :1]
    span = tc[:, -1:].clamp_min(torch.finfo(F64).tiny)
    s = tc / span
    basis = torch.stack([s**j for j in range(min(2, n - 1) + 1)], -1)
    coef = torch.linalg.pinv(basis) @ q[:, :n]
    return coef[:, 0], coef[:, 1] / span


def momentum_for_velocity(
    f: Callable[[Tensor | None, Tensor], Tensor],
    q: Tensor,
    v: Tensor,
    iters: int = 8,
    h_rel: float = 6e-6,
) -> tuple[Tensor, Tensor]:
    """``p`` with ``f(q, p)[:k] = v``: ``q, v (N, k)`` -> ``p (N, k)`` and ``solved (N,)``.

    Newton from ``p = v``, ``∂f_q/∂p`` by central differences of step
    ``h_rel·(1 + |p_i|)`` (all ``2k + 1`` evaluations per row in one call of ``f``);
    the ``p`` with the smallest ``‖f_q − v‖`` is kept. ``solved``: that residual is
    below ``1e-6·(1 + ‖v‖)``. Rows whose Jacobian is singular or non-finite at
    ``p = v`` get ``p = s·v``, ``s`` the median ``‖p‖/‖v‖`` over the solved rows (1 if
    none)."""
    N, k = q.shape
    eye = torch.eye(k, dtype=F64, device=q.device)
    p, best = v.clone(), v.clone()
    best_res = torch.full((N,), torch.inf, dtype=F64, device=q.device)
    singular0 = torch.zeros(N, dtype=torch.bool, device=q.device)
    for i in range(iters + 1):
        h = ((p + h_rel * (1 + p.abs())) - p)[:, None, :] * eye  # (N, k, k): row i moves p_i
        ps = torch.cat(
            [p[None], (p[:, None] + h).transpose(0, 1), (p[:, None] - h).transpose(0, 1)]
        )
        y = torch.cat([q.expand(2 * k + 1, N, k), ps], -1).reshape(-1, 2 * k)
        fq = f(None, y)[:, :k].reshape(2 * k + 1, N, k)
        g = fq[0] - v
        res = g.norm(dim=-1).nan_to_num(torch.inf)
        better = res < best_res
        best, best_res = torch.where(better[:, None], p, best), torch.where(better, res, best_res)
        if i == iters:
            break
        diag = h.diagonal(dim1=1, dim2=2)  # (N, k)
        jac = ((fq[1 : k + 1] - fq[k + 1 :]) / (2 * diag.T[:, :, None])).permute(1, 2, 0)
        step, info = torch.linalg.solve_ex(jac.nan_to_num(), g.nan_to_num())
        failed = (info != 0) | ~torch.isfinite(jac).flatten(1).all(-1)
        if i == 0:
            singular0 = failed
        p = torch.where(failed[:, None], p, p - step)
    solved = best_res <= 1e-6 * (1 + v.norm(dim=-1))
    vn = v.norm(dim=-1)
    ratio = best.norm(dim=-1) / vn
    usable = solved & ~singular0 & (vn > 0) & torch.isfinite(ratio)
    s = ratio[usable].median() if bool(usable.any()) else torch.ones((), dtype=F64)
    best = torch.where(singular0[:, None], s.to(v.device) * v, best)
    return best, solved & ~singular0


@dataclass
class _Fit:
    """The least-squares problem of a batch: rollouts of ``f`` read at each row's times
    ``t (B, M)`` against the observed positions ``q (B, M, k)``; ``rows`` pick a subset."""

    f: Callable[[Tensor | None, Tensor], Tensor]
    t: Tensor
    q: Tensor
    method: str
    substeps: int | Tensor

    def positions(self, z: Tensor, rows: Tensor) -> Tensor:
        """The first ``k`` coordinates of the rollouts from ``z (R·N, 2k)``, ``R`` starts
        per row of ``rows (N,)`` (repeated row-block by row-block), at their rows' times:
        ``(R·N, M, k)``."""
        t = self.t[rows].repeat(z.shape[0] // len(rows), 1)
        return odeint_windows(self.f, z, t, self.method, self.substeps)[..., : self.q.shape[-1]]

    def costs(self, z: Tensor, rows: Tensor) -> Tensor:
        """``Σ_{j,i} (q_i(t_j; z) − q_ji)²`` per start of ``z (R·N, 2k)`` as :meth:`positions`:
        ``(R, N)``, ``inf`` where non-finite."""
        pred = self.positions(z, rows).reshape(-1, len(rows), *self.q.shape[1:])
        sq = ((pred - self.q[rows]) ** 2).flatten(2).sum(-1)
        return sq.nan_to_num(torch.inf, torch.inf)

    def ranking(self, field: Any, dtype: str | torch.dtype | None) -> _Fit:
        """The coarse search's cheaper problem: one step per interval, the field in
        float32 (:func:`ranking_field`). (Every other sample at twice the step ranks
        worse: a trained pendulum HNN's seed-0 position MSE 0.86 -> 1.47.)"""
        return _Fit(ranking_field(field, dtype) or self.f, self.t, self.q, self.method, 1)

    def residual_and_jacobian(self, z: Tensor, rows: Tensor, h_rel: float) -> tuple[Tensor, Tensor]:
        """Residual ``r = q(t; z) − q`` flattened to ``(N, M·k)`` for starts ``z (N, 2k)`` of
        ``rows (N,)``, and its forward-difference Jacobian ``∂r/∂z (N, M·k, 2k)`` (steps
        ``h_rel·(1 + |z_i|)``): one rollout of ``(2k + 1)·N`` rows."""
        N, D = z.shape
        h = (z + h_rel * (1 + z.abs())) - z  # exactly representable offsets
        moved = z[None] + torch.eye(D, dtype=F64, device=z.device)[:, None, :] * h[None]
        out = self.positions(torch.cat([z[None], moved]).reshape(-1, D), rows)
        out = out.reshape(D + 1, N, -1)
        r = out[0] - self.q[rows].flatten(1)
        return r, ((out[1:] - out[0]) / h.T[:, :, None]).permute(1, 2, 0)


def _check_rows(t: Tensor, q: Tensor) -> Tensor:
    """``(B,)`` bool: rows with a non-finite or decreasing time or a non-finite position."""
    finite = torch.isfinite(t).all(-1) & torch.isfinite(q).flatten(1).all(-1)
    increasing = (t.diff(dim=-1).nan_to_num(-1.0) >= 0).all(-1)
    return ~(finite & increasing)


def observe(
    field: Any,
    t: Tensor,
    q: Tensor,
    *,
    method: str = "rk4",
    substeps: int | Tensor = 1,
    iters: int = 20,
    fits: Sequence[int | None] = (3, 5, None),
    scales: Sequence[float] = (0.5, 0.7, 1.0, 1.4, 2.0),
    newton_iters: int = 8,
    grid: int = 21,
    dtype: str | torch.dtype | None = "float64",
    p_bound: Tensor | float | None = None,
) -> Observation:
    """Infer each row's start ``(q₀, p₀)`` from its observed positions (module docstring).

    Args:
        field: a model, a model's ``.field``, or anything with ``vector_field(t, y)`` on
            states ``(N, 2k)`` (a :class:`~hnn_pl.systems.HamiltonianSystem`).
        t: ``(M,)`` times shared by all rows, or ``(B, M)`` per row; non-decreasing.
        q: ``(B, M, k)`` observed positions, ``M >= 2``.
        method: fixed-step method of the rollouts (:data:`~hnn_pl.integrate.WINDOW_METHODS`).
        substeps: steps per interval between samples (an int, or a ``(M − 1,)`` tensor)
            of the Levenberg–Marquardt stage; the coarse search, which only ranks
            candidates, takes one.
        iters: Levenberg–Marquardt iterations at most.
        fits: numbers of leading samples the velocity is fitted over (``None``: all);
            values above ``M`` count as ``M``, below 2 are dropped.
        scales: factors ``c`` of the coarse search's candidates ``(q̂₀, c·p)``.
        newton_iters: Newton iterations of ``f(q̂₀, p)[:k] = v̂₀``.
        grid: points of the coarse search's momentum grid (``k ≤ 2``; 0: none); over
            100 windows of trained seed-0 pendulum and spring HNNs, 21 never ended
            worse than 41 (11 did once).
        dtype: the field's evaluation dtype (:func:`float64_field`).
        p_bound: ``|p_i| ≤ p_bound_i`` for every candidate and iterate (a scalar or
            ``(k,)``; ``None``: unbounded), e.g. :func:`training_momentum_bound`.

    Returns:
        an :class:`Observation`; ``y0 (B, 2k)`` float64 on ``q``'s device.
    """
    if q.ndim != 3 or q.shape[1] < 2:
        raise ValueError(f"observe needs positions q (B, M, k) with M >= 2, got {tuple(q.shape)}")
    B, M, k = q.shape
    t = t.to(device=q.device, dtype=F64)
    t = t.expand(B, -1) if t.ndim == 1 else t
    if t.shape != (B, M):
        raise ValueError(f"observe: times {tuple(t.shape)} do not match positions (B, M) = {B, M}")
    q = q.to(F64)
    bad = _check_rows(t, q)
    t = torch.where(bad[:, None], torch.arange(M, dtype=F64, device=q.device), t)
    q = torch.where(bad[:, None, None], 0.0, q)
    f, eps = float64_field(field, dtype)
    fit = _Fit(f, t, q, method, substeps)
    rows = torch.arange(B, device=q.device)

    sizes = sorted({M if n is None else min(n, M) for n in fits} - {0, 1}) or [M]
    fitted = [fit_position_velocity(t, q, n) for n in sizes]
    q0 = torch.cat([a for a, _ in fitted])
    v0 = torch.cat([v for _, v in fitted])
    p0, _ = momentum_for_velocity(f, q0, v0, newton_iters, eps ** (1 / 3))
    bound = None
    if p_bound is not None:
        bound = torch.as_tensor(p_bound, dtype=F64, device=q.device).expand(k).clone()
        if not bool((torch.isfinite(bound) & (bound > 0)).all()):
            raise ValueError(f"observe: p_bound must be finite and > 0, got {bound.tolist()}")
    z, cost = _coarse_search(fit.ranking(field, dtype), q0, p0, scales, grid, bound)
    diverged = ~torch.isfinite(cost) & ~bad
    z = torch.where(diverged[:, None], torch.cat([fitted[-1][0], p0[-B:]], -1), z)

    status = torch.full((B,), int(ObserverStatus.MAX_ITERS), dtype=torch.long, device=q.device)
    status[bad] = ObserverStatus.BAD_INPUT
    status[diverged] = ObserverStatus.DIVERGED
    tols = (eps**0.5, 0.01 * eps**0.5, max(FTOL, 16 * eps))
    z, status, iterations, cost = _levenberg_marquardt(fit, z, status, iters, *tols, bound)
    unscored = cost.isnan()
    if bool(unscored.any()):
        cost[unscored] = fit.costs(z[unscored], rows[unscored])[0]
    rms = (cost / (M * k)).sqrt()
    z = torch.where(bad[:, None], torch.nan, z)
    rms = torch.where(bad | diverged, torch.nan, rms)
    return Observation(z, rms, status, iterations)


def _coarse_search(
    fit: _Fit,
    q0: Tensor,
    p0: Tensor,
    scales: Sequence[float],
    grid: int = 0,
    bound: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Stage 3 of the module docstring: of the candidates ``(q̂₀, c·p)`` for the ``F`` fits
    (``q0``, ``p0 (F·B, k)``, fit-major) and each ``c`` of ``scales`` (momenta clipped to
    ``bound (k,)`` when given), each row's best start ``(B, 2k)`` and its cost ``(B,)``
    (``inf``: none was finite), all rolled out in one call of one step per interval."""
    B, k = fit.q.shape[0], p0.shape[-1]
    c = torch.tensor(list(scales) or [1.0], dtype=F64, device=q0.device)
    cand = torch.cat([q0.expand(len(c), -1, -1), c[:, None, None] * p0], -1).reshape(-1, 2 * k)
    if grid and k <= 2:
        cand = torch.cat([cand, _momentum_grid(q0[-B:], p0, grid, bound)])
    if bound is not None:
        cand = torch.cat(
            [cand[:, :k], torch.maximum(torch.minimum(cand[:, k:], bound), -bound)], -1
        )
    cost = fit.costs(cand, torch.arange(B, device=q0.device))
    best = cost.argmin(0)
    z = cand.reshape(cost.shape[0], B, -1)[best, torch.arange(B, device=q0.device)]
    return z, cost.min(0).values


def _momentum_grid(q0: Tensor, p0: Tensor, n: int, bound: Tensor | None = None) -> Tensor:
    """Candidates ``(q̂₀, p)`` with ``p`` on a grid of about ``n`` points (``⌈n^{1/k}⌉`` per
    axis) spanning ``±3·median |p|`` of the Newton momenta ``p0 (F·B, k)`` (at most
    ``±bound_i`` on axis ``i``): starts that do not depend on the velocity fit, for rows
    whose fit lies near a turning point or a wrong basin of the learned field.
    ``q0 (B, k)``; returns ``(n^k·B, 2k)``."""
    k = p0.shape[-1]
    finite = p0[torch.isfinite(p0).all(-1)]
    span = 3 * (finite.abs().median() if len(finite) else torch.ones((), dtype=F64)) + 1e-3
    span = span.expand(k) if bound is None else torch.minimum(span, bound)
    per_axis = max(3, round(n ** (1 / k)))
    unit = torch.linspace(-1, 1, per_axis, dtype=F64, device=p0.device)
    points = torch.cartesian_prod(*[unit * s for s in span]).reshape(-1, k)
    B = q0.shape[0]
    return torch.cat(
        [q0.expand(len(points), B, k), points[:, None, :].expand(-1, B, k)], -1
    ).reshape(-1, 2 * k)


def _levenberg_marquardt(
    fit: _Fit,
    z: Tensor,
    status: Tensor,
    iters: int,
    h_rel: float,
    xtol: float,
    ftol: float,
    bound: Tensor | None = None,
) -> tuple[Tensor, Tensor, int, Tensor]:
    """Stage 4 of the module docstring on the rows whose ``status`` is ``MAX_ITERS``
    (each trial's momenta clipped to ``bound (k,)`` when given, the step taken as the
    clipped one);
    returns the starts, the statuses (``OK`` for the rows that converged), the
    iterations run and each row's final sum of squares ``(B,)`` (NaN: a row it did not
    run on).

    Damping as Nielsen (1999): with the gain ratio ``ρ`` of the actual to the
    Gauss–Newton model's decrease, an accepted step (``ρ > 0``) multiplies ``λ`` by
    ``max(1/3, 1 − (2ρ − 1)³)`` and resets ``ν = 2``; a rejected one multiplies ``λ``
    by ``ν`` and doubles ``ν``."""
    status = status.clone()
    total = torch.full(status.shape, torch.nan, dtype=F64, device=z.device)
    active = (status == ObserverStatus.MAX_ITERS).nonzero().flatten()
    if not len(active) or iters < 1:
        return z, status, 0, total
    z = z.clone()
    za = z[active]
    r, jac = fit.residual_and_jacobian(za, active, h_rel)
    cost = (r**2).sum(-1).nan_to_num(torch.inf, torch.inf)
    lam = torch.full_like(cost, _LAMBDA0)
    nu = torch.full_like(cost, 2.0)
    iterations = 0
    for iterations in range(1, iters + 1):  # noqa: B007 (the count is returned)
        a = jac.transpose(1, 2) @ jac
        g = (jac.transpose(1, 2) @ r[..., None])[..., 0]
        d = a.diagonal(dim1=1, dim2=2)
        d = d.clamp_min(1e-12 * d.amax(-1, keepdim=True) + torch.finfo(F64).tiny)
        step, info = torch.linalg.solve_ex(a + torch.diag_embed(lam[:, None] * d), g)
        solved = (info == 0) & torch.isfinite(step).all(-1) & torch.isfinite(jac).flatten(1).all(-1)
        step = torch.where(solved[:, None], step, 0.0)
        if bound is not None:
            k = len(bound)
            p = torch.maximum(torch.minimum(za[:, k:] - step[:, k:], bound), -bound)
            step = torch.cat([step[:, :k], za[:, k:] - p], -1)
        trial = za - step
        r_new, jac_new = fit.residual_and_jacobian(trial, active, h_rel)
        cost_new = (r_new**2).sum(-1).nan_to_num(torch.inf, torch.inf)
        accept = (cost_new < cost) & solved
        predicted = (step * (g + lam[:, None] * d * step)).sum(-1)
        rho = ((cost - cost_new) / predicted).nan_to_num(0.0, 0.0, 0.0)
        small = solved & (step.norm(dim=-1) <= xtol * (1 + za.norm(dim=-1)))
        flat = (accept & (cost - cost_new <= ftol * cost)) | (solved & (predicted <= ftol * cost))
        done = flat | small | (lam >= _LAMBDA_MAX)
        za = torch.where(accept[:, None], trial, za)
        r = torch.where(accept[:, None], r_new, r)
        jac = torch.where(accept[:, None, None], jac_new, jac)
        cost = torch.where(accept, cost_new, cost)
        shrink = (1 - (2 * rho - 1) ** 3).clamp_min(1 / 3)
        lam = torch.where(accept, lam * shrink, lam * nu).clamp(1e-15, _LAMBDA_MAX)
        nu = torch.where(accept, 2.0, 2 * nu)
        z[active] = za
        total[active] = cost
        status[active[done]] = ObserverStatus.OK
        keep = ~done
        if not bool(keep.any()):
            break
        active, za, r, jac, cost, lam, nu = (x[keep] for x in (active, za, r, jac, cost, lam, nu))
    return z, status, iterations, total


def training_momentum_bound(
    model: Any, dm: Any = None, factor: float = MOMENTUM_BOUND
) -> Tensor | None:
    """``factor · max |p_i|`` over the states a trained model was trained on: ``(k,)``
    float64, the observer's ``p_bound``.

    The momenta are the model's learned states' (``model.states (S, 2k)``: from
    positions alone, in the model's own gauge) when it holds them and its field runs on
    the data's coordinates, else those of ``dm``'s training inputs ``x_train (N, 2k)``
    when ``dm`` serves states. ``None`` (unbounded) for anything else: a system, a pixel
    model, data of positions alone without learned states."""
    if not isinstance(model, nn.Module) or not hasattr(model, "field"):
        return None
    states = getattr(model, "states", None)
    canonical = getattr(model, "coordinates", "canonical") == "canonical"
    if isinstance(states, Tensor) and states.ndim == 2 and canonical:
        y = states.detach()
    elif dm is not None and getattr(dm, "observe", "states") == "states":
        y = getattr(dm, "x_train", None)
    else:
        return None
    width = int(getattr(model, "hparams", {}).get("input_dim", 0))
    if y is None or y.ndim != 2 or y.shape[-1] != width or not len(y):
        return None
    bound = factor * y[:, width // 2 :].double().abs().amax(0).cpu()
    return bound if bool((torch.isfinite(bound) & (bound > 0)).all()) else None


def infer_starts(field: Any, t: Tensor, q: Tensor, **kw: Any) -> Tensor:
    """:func:`observe`'s starts ``(B, 2k)`` float64 from positions ``q (B, M, k)`` at
    ``t (M,)`` or ``(B, M)``; ``kw`` as :func:`observe`. A row whose input is bad is
    NaN (a rollout from it stops at once as diverged)."""
    return observe(field, t, q, **kw).y0


@dataclass
class PositionsWindow:
    """Observed positions to infer starts from: ``t (B, M)`` float64 times since each
    row's first sample, ``q (B, M, k)`` float64 positions, ``t0 (B,)`` float64 the file's
    time of each row's first sample."""

    t: Tensor
    q: Tensor
    t0: Tensor


def read_positions_window(path: str | Path, k: int) -> PositionsWindow:
    """A file of positions windows, checked: a CSV ``trajectory,time,q1,…,qk`` (or
    ``trajectory,time,q`` for ``k = 1``; a recording's format, one window per
    trajectory, the first ``M`` samples of each with ``M`` the shortest trajectory's
    count), or a ``torch.save``-d dict ``{"q": (B, M, k), "t": (M,) or (B, M)}``.

    Raises:
        ValueError: one line, ``starts PATH: what is wrong`` — an unreadable file, a
            states CSV, missing keys, a shape other than ``(B, M, k)`` with ``M >= 2``,
            a non-finite value, times not strictly increasing within a row.
    """
    path = Path(path)
    if path.suffix == ".csv":
        return _csv_window(path, k)
    try:
        obj = torch_load(path)
    except Exception:  # noqa: BLE001 - any unreadable file is the same user error
        raise ValueError(f"starts {path}: cannot be read as a torch-saved dict") from None
    return _dict_window(path, obj, k)


def _csv_window(path: Path, k: int) -> PositionsWindow:
    from hnn_pl.data.recording import load_recording

    try:
        rec = load_recording(path)
    except ValueError as err:
        raise ValueError(f"starts {str(err).removeprefix('recording ')}") from None
    if not rec.positions:
        raise ValueError(
            f"starts {path}: holds states (q, p); a positions window's header is "
            f"trajectory,time,{','.join(f'q{i}' for i in range(1, k + 1))}"
        )
    if rec.y.shape[-1] != k:
        raise ValueError(f"starts {path}: {rec.y.shape[-1]} position columns; the model has {k}")
    counts = torch.bincount(rec.traj)
    m = int(counts.min())
    rows = (torch.cumsum(counts, 0) - counts)[:, None] + torch.arange(m)
    return PositionsWindow(rec.t[rows], rec.y[rows], rec.t0)


def _dict_window(path: Path, obj: Any, k: int) -> PositionsWindow:
    expected = f'expected a dict {{"q": (B, M, {k}), "t": (M,) or (B, M)}}'
    if not isinstance(obj, dict):
        raise ValueError(f"starts {path}: holds a {type(obj).__name__}; {expected}")
    if not {"q", "t"} <= set(obj):
        raise ValueError(f"starts {path}: a dict with keys {sorted(map(str, obj))}; {expected}")
    q, t = obj["q"], obj["t"]
    for name, x in (("q", q), ("t", t)):
        if not torch.is_tensor(x) or not x.is_floating_point():
            raise ValueError(f"starts {path}: {name!r} is not a float tensor; {expected}")
    if q.ndim != 3 or q.shape[-1] != k or q.shape[1] < 2 or q.shape[0] == 0:
        raise ValueError(f"starts {path}: 'q' has shape {tuple(q.shape)}; {expected}, M >= 2")
    B, M = q.shape[:2]
    if t.shape not in ((M,), (B, M)):
        raise ValueError(
            f"starts {path}: 't' has shape {tuple(t.shape)}; 'q' needs ({M},) or {B, M}"
        )
    t, q = t.to(F64).expand(B, M), q.to(F64)
    bad = ~(torch.isfinite(q).flatten(1).all(-1) & torch.isfinite(t).all(-1))
    if bool(bad.any()):
        raise ValueError(f"starts {path}: rows {_few(bad)} hold a value that is not finite")
    back = ~(t.diff(dim=-1) > 0).all(-1)
    if bool(back.any()):
        raise ValueError(f"starts {path}: times not strictly increasing in rows {_few(back)}")
    return PositionsWindow(t - t[:, :1], q, t[:, 0].clone())


def _few(rows: Tensor) -> str:
    """``[0, 3, 7]`` or ``[0, 1, 2, 3, 4]...``: the first five flagged rows of ``(B,)``."""
    index = rows.nonzero().flatten().tolist()
    return f"{index[:5]}{'...' if len(index) > 5 else ''}"
