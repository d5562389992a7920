"""Every score of a rollout (:class:`~hnn_pl.evaluation.base.Rollout`), and the
statistics the reports share.

Energy MSE of one trajectory is ``mean_t (E(y_true(t)) − E(y_pred(t)))²``; the reported
value is the mean over trajectories, and its "±" is the standard deviation of
``n_groups`` group means (trajectories split into equal consecutive groups) divided by
``√n_groups``, as the reference README reports it.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.evaluation.base import Rollout
from hnn_pl.evaluation.observer import float64_field


def observed_mean(x: Tensor, dim: int | tuple[int, ...] | None = None) -> Tensor:
    """``x.mean(dim)``; with ``NaN`` in ``x`` (unobserved truth) the mean of the rest."""
    if not bool(torch.isnan(x).any()):
        return x.mean() if dim is None else x.mean(dim)
    return x.nanmean() if dim is None else x.nanmean(dim)


def mse(a: Tensor, b: Tensor) -> Tensor:
    """``mean (a − b)²`` over every element of ``a`` and ``b`` (one shape, or
    broadcast): a scalar. NaN anywhere gives NaN (see :func:`state_mse` for a truth
    with unobserved entries)."""
    return ((a - b) ** 2).mean()


def max_abs_error(a: Tensor, b: Tensor) -> Tensor:
    """``max |a − b|`` over every element (one shape, or broadcast): a scalar."""
    return (a - b).abs().max()


def mean_abs_error(a: Tensor, b: Tensor) -> Tensor:
    """``mean |a − b|`` over every element (one shape, or broadcast): a scalar."""
    return (a - b).abs().mean()


def grouped_mean(per_trajectory: Tensor, n_groups: int) -> tuple[float, float]:
    """Mean over trajectories and its "±": std of ``n_groups`` group means / √n_groups
    (``nan`` with fewer trajectories than groups, or one group)."""
    x = per_trajectory.double()
    n = (len(x) // n_groups) * n_groups
    if n_groups < 2 or n == 0:
        return float(x.mean()), math.nan
    groups = x[:n].reshape(n_groups, -1).mean(1)
    return float(x.mean()), float(groups.std() / math.sqrt(n_groups))


def split_loss(field: nn.Module, x: Tensor, dx: Tensor) -> tuple[float, float]:
    """MSE of ``field.vector_field(x)`` against ``dx`` over a whole split ``(N, D)``, and
    the reference's "±": std of the per-element squared errors / √N."""
    with torch.no_grad():
        sq = (field.vector_field(None, x) - dx) ** 2
    return float(sq.mean()), float(sq.double().std() / math.sqrt(len(x)))


def slope(t: Tensor, m: Tensor) -> Tensor:
    """Least-squares slope of ``m (T,)`` against ``t (T,)``."""
    tc = t - t.mean()
    return (tc * (m - m.mean())).sum() / (tc * tc).sum()


def energy_mse_per_trajectory(r: Rollout) -> Tensor:
    """``mean_t (E(y_true) − E(y_pred))²``: ``(B,)`` (over observed times);
    :func:`energy_mse_of` of ``r.e_true`` and ``r.e_pred``."""
    return energy_mse_of(r.e_true, r.e_pred)


def energy_mse_of(e_true: Tensor, e_pred: Tensor) -> Tensor:
    """``mean_t (e_true − e_pred)²`` of energies ``(T, B)`` per trajectory: ``(B,)``,
    over the times where ``e_true`` is observed (not NaN; :func:`observed_mean`)."""
    return observed_mean((e_true - e_pred) ** 2, 0)


def state_mse(y_true: Tensor, y_pred: Tensor) -> Tensor:
    """``mean_{t,b,d} (y_true − y_pred)²`` of states ``(T, B, D)``: a scalar, over the
    entries where ``y_true`` is observed (not NaN; :func:`observed_mean`)."""
    return observed_mean((y_true - y_pred) ** 2)


def state_mse_per_trajectory(y_true: Tensor, y_pred: Tensor) -> Tensor:
    """``mean_{t,d} (y_true − y_pred)²`` of states ``(T, B, D)`` per trajectory: ``(B,)``,
    over the entries where ``y_true`` is observed (not NaN; :func:`observed_mean`)."""
    return observed_mean((y_true - y_pred) ** 2, (0, 2))


def energy_conservation_mse(e: Tensor) -> Tensor:
    """``mean_{t,b} (E(y_t) − E(y_0))²`` of energies ``e (T, B)`` along trajectories whose
    truth conserves ``E``: the energy error without a reference trajectory; a scalar."""
    return mse(e, e[:1])


def max_energy_drift(e: Tensor, e0: Tensor, scale: Tensor | float) -> Tensor:
    """``max_{t,b} |E(y_t) − E(y_0)| / scale`` of energies ``e (T, B)`` from their
    starts' ``e0 (B,)``, ``scale`` a float or ``(B,)`` (e.g. ``|E(y_0)|``): a scalar."""
    return ((e - e0).abs() / scale).max()


def h_spread(field: nn.Module, x: Tensor) -> Tensor:
    """``std_n H_θ(x_n)`` of ``field.hamiltonian`` over inputs ``x (N, D)``: the
    yardstick of :func:`h_drift` (``H_θ`` carries an arbitrary additive constant and
    scale); a scalar, without gradients."""
    with torch.no_grad():
        return field.hamiltonian(x).std()


def h_excursion(h: Tensor) -> Tensor:
    """``max_t |H_θ(y_t) − H_θ(y_0)|`` per row of ``h (T, B)``: ``(B,)``."""
    return (h - h[0]).abs().amax(0)


def h_drift(h: Tensor, scale: Tensor | float) -> Tensor:
    """``max_t |H_θ(y_t) − H_θ(y_0)| / (|H_θ(y_0)| + scale)`` per row of ``h (T, B)``:
    ``(B,)``. ``H_θ`` carries an arbitrary additive constant, so ``|H_θ(y_0)|`` alone is
    no yardstick; ``scale`` (the spread of ``H_θ`` over training inputs) measures the
    drift against the spread of the learned energy over the data."""
    return h_excursion(h) / (h[0].abs() + scale)


def h_spread_drift(h: Tensor, scale: Tensor | float) -> Tensor:
    """``max_t |H_θ(y_t) − H_θ(y_0)| / scale`` per row of ``h (T, B)``: ``(B,)``; the
    excursion of ``H_θ`` against its spread alone (:func:`h_spread`), without
    :func:`h_drift`'s ``|H_θ(y_0)|``."""
    return h_excursion(h) / scale


def conserved_drift(r: Rollout) -> Tensor:
    """:func:`h_drift` of ``r.h_pred`` with ``r.h_scale``, mean over rows."""
    return h_drift(r.h_pred, r.h_scale).mean()


def motion_error(y_pred: Tensor, y_true: Tensor, fraction: float = 0.1) -> Tensor:
    """Relative state error over the first ``fraction`` of the points (at least three):
    ``Σ (y_pred − y_true)² / Σ (y_true − y_true[0])²`` over ``(T, B, D)`` states.

    1 for a model that does not move, ≈ 0.25 for one at half the true speed, → 0 for
    one that has learned the motion. Early points only: over long horizons any small
    frequency error decorrelates the phase, so a whole-horizon state error cannot tell
    a good model from a still one; an energy error alone cannot either (a state that
    does not move conserves every energy).
    """
    k = max(3, math.ceil(fraction * y_true.shape[0]))
    total = torch.nansum if bool(torch.isnan(y_true[:k]).any()) else torch.sum
    moved = total((y_true[:k] - y_true[:1]) ** 2)
    return total((y_pred[:k] - y_true[:k]) ** 2) / moved.clamp_min(torch.finfo(moved.dtype).tiny)


def valid_time(r: Rollout, threshold: float = 0.025) -> Tensor:
    """Valid prediction time per trajectory, ``(B,)``: the first ``t − t₀`` at which the
    normalised state error ``‖y_pred − y_true‖ / rms_t ‖y_true‖`` exceeds ``threshold``
    (the whole horizon if it never does)."""
    return valid_time_of(r.t, r.y_pred, r.y_true, threshold)


def valid_time_of(t: Tensor, y_pred: Tensor, y_true: Tensor, threshold: float = 0.025) -> Tensor:
    """:func:`valid_time` of predictions ``y_pred`` against ``y_true``, both ``(T, B, d)``,
    at times ``t (T,)``: ``(B,)``."""
    scale = observed_mean((y_true**2).sum(-1), 0).sqrt()
    err = (y_pred - y_true).norm(dim=-1) / scale.clamp_min(torch.finfo(scale.dtype).tiny)
    over = err > threshold
    first = torch.where(over.any(0), over.to(torch.uint8).argmax(0), len(t) - 1)
    return t[first] - t[0]


def _mean_where_observed(sq: Tensor, truth: Tensor, dim: int | None = None) -> Tensor:
    """Mean of ``sq`` over the entries where ``truth`` is not NaN (observed); a NaN of a
    prediction at an observed entry stays NaN."""
    seen = ~torch.isnan(truth)
    total = torch.where(seen, sq, 0.0)
    if dim is None:
        return total.sum() / seen.sum()
    return total.sum(dim) / seen.sum(dim)


def position_mse(y_pred: Tensor, q_true: Tensor, k: int) -> Tensor:
    """Position MSE ``mean_{t,b,i<k} (y_pred[..., i] − q_true[..., i])²``: the first ``k``
    coordinates of predicted states (or positions) ``(T, B, ≥k)`` against the clean true
    positions (or states) ``(T, B, ≥k)``, over the observed entries (NaN in the truth);
    a scalar. Invariant under every canonical change that keeps ``q``."""
    q = q_true[..., :k]
    return _mean_where_observed((y_pred[..., :k] - q) ** 2, q)


def position_mse_per_trajectory(y_pred: Tensor, q_true: Tensor, k: int) -> Tensor:
    """:func:`position_mse` per trajectory: ``mean_{t,i<k}`` over the observed entries,
    ``(B,)``."""
    q = q_true[..., :k]
    return _mean_where_observed((y_pred[..., :k] - q) ** 2, q, (0, 2))


def position_valid_time(
    t: Tensor, y_pred: Tensor, q_true: Tensor, k: int, threshold: float = 0.025
) -> Tensor:
    """:func:`valid_time` on positions: the first ``t − t₀`` at which
    ``‖q_pred − q_true‖ / rms_t ‖q_true‖`` exceeds ``threshold``, from the first ``k``
    coordinates of ``y_pred`` and ``q_true`` (each ``(T, B, ≥k)``) at ``t (T,)``;
    ``(B,)``."""
    return valid_time_of(t, y_pred[..., :k], q_true[..., :k], threshold)


def velocity_energy(system: Any, field: Any, y: Tensor) -> Tensor:
    """The true energy from positions and the field's own velocities along its path:
    ``E(q, q̇) = system.energy_qv(q, f_θ(y)[..., :k])`` for states ``y (T, B, 2k)`` ->
    ``(T, B)`` float64, ``f_θ`` = ``field.vector_field`` of a model, its ``.field`` or a
    system, evaluated in float64 (:func:`~hnn_pl.evaluation.observer.float64_field`).
    Gauge-invariant: ``q̇ = ∂H_θ/∂p`` is the same in every canonical frame that keeps
    ``q``."""
    k = y.shape[-1] // 2
    flat = y.reshape(-1, y.shape[-1]).to(torch.float64)
    f, _ = float64_field(field)
    v = f(None, flat)[:, :k]
    return system.energy_qv(flat[:, :k], v).reshape(y.shape[:-1])


def velocity_energy_mse_per_trajectory(
    system: Any, field: Any, y_pred: Tensor, e_true: Tensor
) -> Tensor:
    """``mean_t (E_true(t) − E(q_pred, q̇_pred)(t))²`` per trajectory, ``(B,)``:
    ``e_true (T, B)`` the true energy of the true path (``system.energy(y_true)``, or a
    recording's), NaN where unobserved (left out); the second term
    :func:`velocity_energy` of ``y_pred (T, B, 2k)``."""
    e = velocity_energy(system, field, y_pred)
    return _mean_where_observed((e_true.to(e.dtype) - e) ** 2, e_true, 0)


def velocity_energy_mse(system: Any, field: Any, y_pred: Tensor, e_true: Tensor) -> Tensor:
    """The mean over trajectories of :func:`velocity_energy_mse_per_trajectory`: a
    scalar."""
    return velocity_energy_mse_per_trajectory(system, field, y_pred, e_true).mean()


def field_error(r: Rollout) -> Tensor:
    """Relative field error on the true states, one number over all of them:
    ``sqrt(Σ_{t,b} ‖f_θ(y_true) − f(y_true)‖²) / sqrt(Σ_{t,b} ‖f(y_true)‖²)`` over the
    ``(T, B, D)`` held-out states (a norm ratio over the whole set, so states where
    ``f`` is near zero cannot dominate it); 0 for the true field, 1 for ``f_θ = 0``."""
    den = (r.f_true**2).sum()
    num = ((r.f_pred - r.f_true) ** 2).sum().sqrt()
    return num / den.sqrt().clamp_min(torch.finfo(den.dtype).tiny)


def energy_drift_slope(r: Rollout, energy: Tensor | None = None) -> Tensor:
    """:func:`slope` in time of ``mean_b (E(t) − E(0)) / |E_true(0)|``, ``E`` the predicted
    energy ``r.e_pred (T, B)`` unless given: the relative drift per unit time (signed;
    with ``energy=r.e_true`` the truth's own, e.g. a measured decay)."""
    e = r.e_pred if energy is None else energy
    rel = observed_mean((e - e[:1]) / r.e_true[:1].abs().clamp_min(1e-12), 1)
    return slope(r.t, rel)


#: the metrics of :func:`score` on the rows that did not diverge, by name
_ON_ROWS = {
    "energy_mse": lambda r: energy_mse_per_trajectory(r).mean(),
    "state_mse": lambda r: state_mse(r.y_true, r.y_pred),
    "motion_error": lambda r: motion_error(r.y_pred, r.y_true),
    "valid_time": lambda r: valid_time(r).mean(),
    "energy_drift_slope": lambda r: energy_drift_slope(r),
    "true_energy_drift_slope": lambda r: energy_drift_slope(r, r.e_true),
}


#: the metrics of :func:`score` for a rollout from observed positions (``r.positions``):
#: the gauge-invariant ones, on the first ``k`` coordinates
_ON_POSITIONS = {
    "energy_mse": lambda r: energy_mse_per_trajectory(r).mean(),
    "position_mse": lambda r: position_mse(r.y_pred, r.y_true, r.positions),
    "motion_error": lambda r: motion_error(
        r.y_pred[..., : r.positions], r.y_true[..., : r.positions]
    ),
    "position_valid_time": lambda r: position_valid_time(
        r.t, r.y_pred, r.y_true, r.positions
    ).mean(),
    "energy_drift_slope": lambda r: energy_drift_slope(r),
    "true_energy_drift_slope": lambda r: energy_drift_slope(r, r.e_true),
}


def report(r: Rollout) -> dict[str, float]:
    """What a report adds to :func:`score`: the "±" ``energy_mse_pm`` of the rows that did
    not diverge (``nan`` with fewer of them than ``r.n_groups``), ``n_trajectories``
    and ``t_end``."""
    out = {"n_trajectories": r.y_pred.shape[1], "t_end": float(r.t[-1])}
    if r.e_true is not None:
        ok = r if r.status is None else r.rows(r.status == 0)
        out["energy_mse_pm"] = grouped_mean(energy_mse_per_trajectory(ok), r.n_groups)[1]
    return out


def score(r: Rollout) -> dict[str, float]:
    """Every metric of a rollout against its truth, unprefixed, over the rows that did
    not diverge (``diverged_rows`` counts the others; all NaN if none is left).

    - ``energy_mse``, ``energy_drift_slope`` and
      ``true_energy_drift_slope`` (the truth's): only when there is an energy;
    - ``state_mse`` ``mean_{t,b,d} (y_true − y_pred)²``, ``motion_error``,
      ``valid_time`` (mean of :func:`valid_time`); for a rollout from observed positions
      (``r.positions``) instead ``position_mse``, ``motion_error`` and
      ``position_valid_time`` on the positions, and ``energy_mse`` of the true energy
      from ``(q, q̇)`` (gauge-invariant);
    - ``conserved_drift`` (HNN); ``field_error`` (when the data gives the true field;
      over every row: it is read on the true states);
    - ``floor_{integrator,chaos}_{energy,state}_mse``: the part of an error that is not
      the model's (state tasks);
    - pixel models: ``pixel_mse`` (decoded vs true frame pairs), ``latent_mse``
      (integrated vs encoded true pairs) and ``probe_mse``.
    """
    diverged = 0 if r.status is None else int((r.status != 0).sum())
    on_truth = {} if r.f_true is None else {"field_error": float(field_error(r))}
    if diverged:
        r = r.rows(r.status == 0)
    table = _ON_ROWS if r.positions is None else _ON_POSITIONS
    names = [n for n in table if r.e_true is not None or "energy" not in n]
    if r.y_true.shape[1] == 0:
        names += ["conserved_drift"] * (r.h_pred is not None)
        return {**dict.fromkeys(names, math.nan), "diverged_rows": float(diverged), **on_truth}
    out = {name: table[name](r) for name in names}
    out["diverged_rows"] = diverged
    if r.h_pred is not None:
        out["conserved_drift"] = conserved_drift(r)
    out.update(on_truth)
    for key, value in (r.floors or {}).items():
        name, kind = key.rsplit("_", 1)
        out[f"floor_{name}_{kind}_mse"] = value.mean()
    if r.has_frames:
        out["pixel_mse"] = mse(r.x_pred, r.x_true)
        out["latent_mse"] = mse(r.z_pred, r.z_true)
        out["probe_mse"] = r.probe_mse
    return {k: float(v) for k, v in out.items()}


# --- stability metrics (stress)


def relative_energy_error(e: Tensor) -> Tensor:
    """``|E_t − E_0| / E_0`` of an energy ``e (T, ...)`` along its first (time) axis:
    the same shape as ``e``."""
    return ((e - e[:1]) / e[:1]).abs()


def drift_stats(t: Tensor, rel: Tensor) -> dict[str, float]:
    """Max, slope (per unit time, least squares of the row mean) and first/last-decile
    means of a relative energy error ``rel (T, B)`` over ``t (T,)``."""
    m = rel.mean(1)
    k = max(1, len(t) // 10)
    return {
        "max": float(rel.max()),
        "slope": float(slope(t, m)),
        "first": float(m[:k].mean()),
        "last": float(m[-k:].mean()),
    }


def return_error(y_back: Tensor, y0: Tensor) -> Tensor:
    """``max |y_back − y_0|`` over every element: how far integrating to ``T`` and back
    misses the start (0 for an exactly reversible method)."""
    return (y_back - y0).abs().max()


# --- the constrained-HNN benchmark's rollout error (chain pendulum)

#: the floor added to the relative error before its logarithm (the reference's 1e-8)
LOG_FLOOR = 1e-8
#: the denominators of :func:`relative_state_error`
DENOMINATORS = ("sum_of_norms", "norm_of_sum")


def relative_state_error(
    z_pred: Tensor, z_true: Tensor, denominator: str = "sum_of_norms"
) -> Tensor:
    """The relative error of states ``(B, T, ...)`` at every time, ``(B, T)``, norms over
    all trailing axes (e.g. Cartesian positions and velocities ``(2, n, 2)``):
    ``‖z − z*‖ / (‖z‖ + ‖z*‖)`` (``"sum_of_norms"``: the published figures and tables,
    bounded by 1) or ``‖z − z*‖ / ‖z + z*‖`` (``"norm_of_sum"``: the reference trainer's
    logged curve); the two agree to first order in the error."""
    if denominator not in DENOMINATORS:
        raise ValueError(f"denominator must be one of {DENOMINATORS}, got {denominator!r}")
    a, b = z_pred.flatten(2), z_true.flatten(2)
    num = (a - b).norm(dim=-1)
    if denominator == "norm_of_sum":
        return num / (a + b).norm(dim=-1)
    return num / (a.norm(dim=-1) + b.norm(dim=-1))


def time_geometric_mean(err: Tensor, dt: float, horizon: float | None = None) -> Tensor:
    """``exp(∫ log(err(t) + 1e-8) dt / horizon)`` of errors ``(B, T)`` sampled every ``dt``
    from ``t = 0``: the trapezoidal rule over the ``T`` samples, divided by ``horizon``
    (default ``(T − 1)·dt``; the reference divides by its nominal 3 s while its samples
    end at 2.97 s): ``(B,)``."""
    horizon = (err.shape[-1] - 1) * dt if horizon is None else horizon
    return torch.exp(torch.trapezoid(torch.log(err + LOG_FLOOR), dx=dt, dim=-1) / horizon)


def relative_rollout_error(
    z_pred: Tensor,
    z_true: Tensor,
    dt: float,
    horizon: float | None = None,
    denominator: str = "sum_of_norms",
) -> Tensor:
    """Per trajectory, the geometric mean over time of :func:`relative_state_error` of
    ``z_pred``, ``z_true`` ``(B, T, ...)`` (:func:`time_geometric_mean`): ``(B,)``. The
    benchmark reports the median over trajectories. A non-finite prediction (a rollout
    that stopped) counts as the largest error, 1."""
    err = relative_state_error(z_pred, z_true, denominator)
    return time_geometric_mean(torch.nan_to_num(err, nan=1.0, posinf=1.0), dt, horizon)
