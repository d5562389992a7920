"""The one rollout-and-score engine, for state and pixel models alike.

:func:`rollout` (``hnn_pl.rollout``) integrates a model from given starts;
:func:`run` rolls it out against a DataModule's held-out truth under a
:class:`~hnn_pl.protocols.Protocol`; :func:`score` computes every metric;
:func:`evaluate` is ``run`` then ``score`` (callbacks, ``predict``, ``reproduce``).
Trajectories are time first, ``(T, B, D)``, as :func:`hnn_pl.odeint` returns them.

Duck-typed, public attributes only. A model: ``field`` (a module with
``vector_field(t, y)`` and, for an HNN, ``hamiltonian(y)``) or is one itself; pixel
models also ``encode``, ``decode``, ``frame_dt``. A DataModule:
``rollout_target(t_end, n_points)``, ``energy(y)``, ``reference_inputs(n)``, optionally
``true_field(t, y)`` (the true ``dy/dt`` at held-out states, for the field error),
``has_energy`` (``False``: no energy metrics); pixel ones also ``rollout_truth``,
``probe_data(n)``, ``canonical``, ``canonical_energy``. A held-out truth may be ``NaN``
where a trajectory has no sample (recordings of several trajectories on the union of
their times); the metrics average over the samples there are.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.integrate import Solution, odeint
from hnn_pl.protocols import Protocol


@dataclass
class Rollout:
    """A rollout and its truth: times ``t (T,)``, states ``y_true``/``y_pred (T, B, D)``
    (``y_pred`` integrated from ``y_true[0]``), energies ``e_true``/``e_pred (T, B)``,
    the learned ``h_pred (T, B)`` (HNN) and ``h_scale`` (std of ``H_θ`` over reference
    inputs). Pixel models: ``y``/``e`` are the linear probe's ``(q, p) = (θ, c·θ̇)``;
    ``z_true``/``z_pred (T, B, L)`` encoded and integrated latents, ``x_true``/``x_pred
    (T, B, 1568)`` frame pairs, ``probe (L + 1, 2)`` with ``(q, p) ≈ [z, 1] @ probe``
    and its training residual ``probe_mse``. ``e_true``/``e_pred`` are ``None`` when
    the DataModule has no energy; ``y_true`` (and ``e_true``) are ``NaN`` at times a
    trajectory was not observed. ``status (B,)``: each row's
    :class:`hnn_pl.integrate.Status` (rows that diverged are NaN after their stop).
    ``floors``: the true system's own errors under the protocol (:func:`error_floors`).
    ``f_true``/``f_pred (T, B, D)``: the true field ``dm.true_field(t, y_true)`` and the
    model's ``f_θ(y_true)`` on the true states (state models whose data gives one)."""

    t: Tensor
    y_true: Tensor
    y_pred: Tensor
    e_true: Tensor | None
    e_pred: Tensor | None
    h_pred: Tensor | None = None
    h_scale: Tensor | float = 0.0
    z_true: Tensor | None = None
    z_pred: Tensor | None = None
    x_true: Tensor | None = None
    x_pred: Tensor | None = None
    probe: Tensor | None = None
    probe_mse: Tensor | float = 0.0
    status: Tensor | None = None
    floors: dict[str, Tensor] | None = None
    f_true: Tensor | None = None
    f_pred: Tensor | None = None

    @property
    def is_pixel(self) -> bool:
        return self.x_pred is not None

    def rows(self, keep: Tensor) -> Rollout:
        """The rollout of the rows ``keep (B,)`` (bool) only."""
        per_row = ("y_true", "y_pred", "e_true", "e_pred", "h_pred")
        per_row += ("z_true", "z_pred", "x_true", "x_pred", "f_true", "f_pred")
        picked = {k: getattr(self, k)[:, keep] for k in per_row if getattr(self, k) is not None}
        status = None if self.status is None else self.status[keep]
        floors = None if self.floors is None else {k: v[keep] for k, v in self.floors.items()}
        return replace(self, **picked, status=status, floors=floors)


def _dtype(protocol_dtype: str | torch.dtype | None) -> torch.dtype | None:
    if protocol_dtype is None or isinstance(protocol_dtype, torch.dtype):
        return protocol_dtype
    return None if protocol_dtype == "model" else getattr(torch, protocol_dtype)


def integrate_field(
    field: nn.Module,
    y0: Tensor,
    t: Tensor,
    method: str = "dopri5",
    dtype: str | torch.dtype | None = torch.float64,
    **kwargs: Any,
) -> tuple[Solution, nn.Module]:
    """The :class:`~hnn_pl.integrate.Solution` of ``field.vector_field`` from ``y0 (B,
    D)`` over ``t (T,)`` (states ``(T, B, D)``; a row that diverges stops alone), and
    the field used: a copy in ``dtype`` (float64 keeps the rollout's error far below
    the model's), or the field itself for ``"model"``/``None``."""
    dtype = _dtype(dtype)
    param = next(field.parameters(), None)
    if dtype is not None and param is not None and param.dtype != dtype:
        field = copy.deepcopy(field).to(dtype)
    dtype = dtype or (param.dtype if param is not None else y0.dtype)
    with torch.no_grad():
        sol = odeint(
            field.vector_field, y0.to(dtype), t.to(dtype), method, return_status=True, **kwargs
        )
    return sol, field


def _learned_h(field: nn.Module, y: Tensor) -> Tensor | None:
    """``H_θ`` along ``y (T, B, D)`` as ``(T, B)``, or ``None`` without ``hamiltonian``."""
    if not hasattr(field, "hamiltonian"):
        return None
    with torch.no_grad():
        return field.hamiltonian(y.flatten(0, 1)).reshape(y.shape[:2])


def is_pixel_model(model: Any) -> bool:
    """Whether ``model`` works on observations through ``encode``/``decode``."""
    return callable(getattr(model, "encode", None)) and callable(getattr(model, "decode", None))


@dataclass
class Trajectories:
    """What :func:`rollout` returns: ``t (T,)``, states ``y (T, B, D)`` (pixel: latents),
    the learned ``h (T, B)`` (HNN), ``energy (T, B)`` (when given), decoded ``frames
    (T, B, input_dim)`` (pixel), and each row's ``status (B,)``
    (:class:`hnn_pl.integrate.Status`; a diverged row is NaN after ``t_stop (B,)``)."""

    t: Tensor
    y: Tensor
    status: Tensor
    t_stop: Tensor
    h: Tensor | None = None
    energy: Tensor | None = None
    frames: Tensor | None = None

    def as_dict(self) -> dict[str, Tensor]:
        return {k: v for k, v in vars(self).items() if v is not None}


def rollout(
    model: Any,
    y0: Tensor,
    t: Tensor,
    method: str = "dopri5",
    dtype: str | torch.dtype | None = "float64",
    energy: Any = None,
    **kwargs: Any,
) -> Trajectories:
    """Integrate a model from ``y0`` over ``t``: ``hnn_pl.rollout(model, y0, t, method=…)``.

    Args:
        model: a state model (``HNN``, ``Baseline``) or a pixel model
            (``AutoencoderHNN``, ``AutoencoderBaseline``), or any module with
            ``vector_field(t, y)``.
        y0: ``(B, D)`` starts; for a pixel model ``(B, input_dim)`` frame pairs,
            encoded first.
        t: ``(T,)`` output times (pixel models: in the latent field's time unit,
            one frame lasting ``model.frame_dt``).
        method: a key of :data:`hnn_pl.integrate.METHODS`.
        dtype: integrate a copy of the field in this dtype (``"model"``: as is).
        energy: optional ``(..., D) -> (...)`` physical energy of the states.
        **kwargs: ``rtol``, ``atol``, ``step_size``, ``options`` of :func:`hnn_pl.odeint`.

    Returns:
        :class:`Trajectories` with states, ``H_θ`` (HNN), energy and frames (pixel).
    """
    was_training = getattr(model, "training", False)
    if isinstance(model, nn.Module):
        model.eval()
    try:
        with torch.no_grad():
            pixel = is_pixel_model(model)
            z0 = model.encode(y0) if pixel else y0
            field = getattr(model, "field", model)
            sol, field = integrate_field(field, z0, torch.as_tensor(t), method, dtype, **kwargs)
            y = sol.y
            out = Trajectories(torch.as_tensor(t).to(y.dtype), y, sol.status, sol.t_stop)
            out.h = _learned_h(field, y)
            if pixel:
                out.frames = model.decode(y.to(z0.dtype))
            if energy is not None:
                out.energy = energy(y)
    finally:
        if isinstance(model, nn.Module):
            model.train(was_training)
    return out


def run(
    model: Any, dm: Any, protocol: Protocol, probe_model: Any = None, floors: bool = True
) -> Rollout:
    """Roll ``model`` out from ``dm``'s held-out starts under ``protocol``.

    State models: starts and truth from ``dm.rollout_target(t_end, n_points)``.
    Pixel models: the first frame pair of each held-out trajectory is encoded, the
    latent field integrated over ``n_points`` frames (``t = k·frame_dt``), decoded,
    and the latents mapped to ``(q, p)`` by an affine least-squares probe fitted on
    ``probe_rows`` encoded training inputs; each model uses its own encoder and probe,
    unless ``protocol.probe_encoder == "hnn"`` and ``probe_model`` is given: then the
    probe is fitted on ``probe_model``'s encodings and reads the model's decoded
    frames through ``probe_model``'s encoder (the reference's evaluation of the
    baseline through the HNN's encoder). ``protocol.start``, ``model_t_end``,
    ``energy_coef``, ``reencode``: see :class:`~hnn_pl.protocols.Protocol`.
    ``floors=False`` skips the state tasks' :func:`error_floors` (the true system's own
    rollouts; time-to-accuracy checks need the model's errors only).
    The models are put in eval mode and restored.
    """
    reader = model if probe_model is None or protocol.probe_encoder == "own" else probe_model
    was_training = model.training, reader.training
    model.eval()
    reader.eval()
    try:
        with torch.no_grad():
            if is_pixel_model(model):
                return _run_pixel(model, dm, protocol, reader)
            return _run_state(model, dm, protocol, floors)
    finally:
        model.train(was_training[0])
        reader.train(was_training[1])


def _device(model: Any) -> torch.device:
    param = next(model.parameters(), None)
    return param.device if param is not None else torch.device("cpu")


def _run_state(model: Any, dm: Any, p: Protocol, floors: bool = True) -> Rollout:
    device = _device(model)
    t, y_true = dm.rollout_target(p.t_end, p.n_points)
    y_true = y_true[:, : p.max_starts].to(device)
    kw = p.solver_kwargs()
    field = getattr(model, "field", model)
    sol, field = integrate_field(field, y_true[0], t.to(device), dtype=p.dtype, **kw)
    y_pred = sol.y
    y_true = y_true.to(y_pred.dtype)
    has_energy = getattr(dm, "has_energy", True)
    e_true, e_pred = (dm.energy(y_true), dm.energy(y_pred)) if has_energy else (None, None)
    r = Rollout(t.to(y_pred.dtype), y_true, y_pred, e_true, e_pred)
    r.status = sol.status
    r.h_pred = _learned_h(field, y_pred)
    if r.h_pred is not None:
        r.h_scale = field.hamiltonian(dm.reference_inputs(p.scale_rows).to(y_pred)).std()
    if floors:
        r.floors = error_floors(dm, r.t, y_true, p)
    f_true = dm.true_field(r.t, y_true) if callable(getattr(dm, "true_field", None)) else None
    if f_true is not None:
        r.f_true = f_true.to(y_pred)
        r.f_pred = field.vector_field(None, y_true.flatten(0, 1)).reshape(y_true.shape)
    return r


#: size of the start perturbation that measures the chaos floor
CHAOS_EPS = 1e-4


def error_floors(dm: Any, t: Tensor, y_true: Tensor, p: Protocol) -> dict[str, Tensor]:
    """How much of a rollout's error is not the model's, per trajectory ``(B,)``:

    - ``integrator``: the true system (``dm.system``) through the protocol's own method,
      step and tolerances, against the truth;
    - ``chaos``: the true system at truth accuracy from starts perturbed by
      ``CHAOS_EPS · N(0, 1)`` (a fixed draw), against the truth: the error any model
      inherits from sensitivity to its start.

    Each as energy MSE and state MSE over time (``{name}_energy``, ``{name}_state``).
    Empty without ``dm.system``.
    """
    system = getattr(dm, "system", None)
    if system is None or not getattr(dm, "has_energy", True):
        return {}
    y0, tt = y_true[0].double(), t.double()
    kw = {k: v for k, v in p.solver_kwargs().items() if k != "method"}
    integ = odeint(system.vector_field, y0, tt, p.method, return_status=True, **kw).y
    gen = torch.Generator().manual_seed(0)
    noise = torch.randn(y0.shape, generator=gen, dtype=torch.float64).to(y0.device)
    chaos = system.trajectory(y0 + CHAOS_EPS * noise, tt)
    e_true, out = dm.energy(y_true.double()), {}
    for name, y in (("integrator", integ), ("chaos", chaos)):
        out[f"{name}_energy"] = observed_mean((dm.energy(y) - e_true) ** 2, 0)
        out[f"{name}_state"] = observed_mean((y - y_true.double()) ** 2, (0, 2))
    return out


def observed_mean(x: Tensor, dim: int | tuple[int, ...] | None = None) -> Tensor:
    """``x.mean(dim)``; with ``NaN`` in ``x`` (unobserved truth) the mean of the rest."""
    if not bool(torch.isnan(x).any()):
        return x.mean() if dim is None else x.mean(dim)
    return x.nanmean() if dim is None else x.nanmean(dim)


def fit_probe(z: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """Affine least squares ``target (N, K) ≈ [z, 1] @ W`` for ``z (N, L)``, in float64:
    ``W (L + 1, K)`` and the mean squared residual."""
    a = torch.cat([z.double(), z.new_ones(len(z), 1, dtype=torch.float64)], -1)
    w = torch.linalg.lstsq(a, target.double()).solution
    return w, ((a @ w - target.double()) ** 2).mean()


def apply_probe(w: Tensor, z: Tensor) -> Tensor:
    """``[z, 1] @ W``: ``(..., L) -> (..., K)`` in float64."""
    return z.double() @ w[:-1] + w[-1]


def _run_pixel(model: Any, dm: Any, p: Protocol, reader: Any) -> Rollout:
    device = _device(model)
    x_train, qp_train = dm.probe_data(p.probe_rows)
    z_train = reader.encode(x_train.to(device))
    probe, probe_mse = fit_probe(z_train, qp_train.to(device))
    if p.start is None:
        t, y_true, x_true = dm.rollout_truth(p.t_end, p.n_points)
        y_true, x_true = y_true[:, : p.max_starts], x_true[:, : p.max_starts].to(device)
    else:
        t, y_true, x_true = dm.trajectory_truth(*p.start, p.n_points or dm.rollout_frames)
        x_true = x_true.to(device)
    z_true = model.encode(x_true)
    if p.model_t_end is None:
        t_model = torch.arange(len(t), dtype=torch.float64, device=device)
    else:
        t_model = torch.linspace(0, p.model_t_end, len(t), dtype=torch.float64, device=device)
    kw = p.solver_kwargs()
    sol, field = integrate_field(
        model.field, z_true[0], t_model * model.frame_dt, dtype=p.dtype, **kw
    )
    z_pred = sol.y
    x_pred = model.decode(z_pred.to(z_true.dtype))
    if p.reencode:
        z_read = reader.encode(x_pred)
    elif reader is not model:
        raise ValueError("a probe on another model's encoder reads decoded frames: reencode=True")
    else:
        z_read = z_pred
    qp_true = dm.canonical(y_true.to(device)).double()
    qp_pred = apply_probe(probe, z_read)
    r = Rollout(
        t=t.double().cpu(),
        y_true=qp_true,
        y_pred=qp_pred,
        e_true=dm.canonical_energy(qp_true, p.energy_coef),
        e_pred=dm.canonical_energy(qp_pred, p.energy_coef),
        z_true=z_true.to(z_pred.dtype),
        z_pred=z_pred,
        x_true=x_true,
        x_pred=x_pred,
        probe=probe,
        probe_mse=probe_mse,
        status=sol.status,
    )
    r.h_pred = _learned_h(field, z_pred)
    if r.h_pred is not None:
        z_own = z_train if reader is model else model.encode(x_train.to(device))
        r.h_scale = field.hamiltonian(z_own.to(z_pred.dtype)).std()
    return r


def energy_mse_per_trajectory(r: Rollout) -> Tensor:
    """``mean_t (E(y_true) − E(y_pred))²``: ``(B,)`` (over observed times)."""
    return observed_mean((r.e_true - r.e_pred) ** 2, 0)


def conserved_drift(r: Rollout) -> Tensor:
    """``mean_b max_t |H_θ(y_t) − H_θ(y_0)| / (|H_θ(y_0)| + scale)``.

    ``H_θ`` carries an arbitrary additive constant, so ``|H_θ(y_0)|`` alone is no
    yardstick; ``scale = r.h_scale`` (the spread of ``H_θ`` over training inputs)
    measures the drift against the spread of the learned energy over the data.
    """
    h = r.h_pred
    return ((h - h[0]).abs().amax(0) / (h[0].abs() + r.h_scale)).mean()


def motion_error(y_pred: Tensor, y_true: Tensor, fraction: float = 0.1) -> Tensor:
    """Relative state error over the first ``fraction`` of the points (at least two):
    ``Σ (y_pred − y_true)² / Σ (y_true − y_true[0])²`` over ``(T, B, D)`` states.

    1 for a model that does not move, ≈ 0.25 for one at half the true speed, → 0 for
    one that has learned the motion. Early points only: over long horizons any small
    frequency error decorrelates the phase, so a whole-horizon state error cannot
    tell a good model from a still one; an energy error alone cannot either (a state
    that does not move conserves every energy).
    """
    k = max(3, math.ceil(fraction * y_true.shape[0]))
    total = torch.nansum if bool(torch.isnan(y_true[:k]).any()) else torch.sum
    moved = total((y_true[:k] - y_true[:1]) ** 2)
    return total((y_pred[:k] - y_true[:k]) ** 2) / moved.clamp_min(torch.finfo(moved.dtype).tiny)


def valid_time(r: Rollout, threshold: float = 0.025) -> Tensor:
    """Valid prediction time per trajectory, ``(B,)``: the first ``t − t₀`` at which the
    normalised state error ``‖y_pred − y_true‖ / rms_t ‖y_true‖`` exceeds ``threshold``
    (the whole horizon if it never does)."""
    scale = observed_mean((r.y_true**2).sum(-1), 0).sqrt()
    err = (r.y_pred - r.y_true).norm(dim=-1) / scale.clamp_min(torch.finfo(scale.dtype).tiny)
    over = err > threshold
    first = torch.where(over.any(0), over.to(torch.uint8).argmax(0), len(r.t) - 1)
    return r.t[first] - r.t[0]


def field_error(r: Rollout) -> Tensor:
    """Relative field error on the true states, one number over all of them:
    ``sqrt(Σ_{t,b} ‖f_θ(y_true) − f(y_true)‖²) / sqrt(Σ_{t,b} ‖f(y_true)‖²)`` over the
    ``(T, B, D)`` states of the held-out trajectories (a norm ratio over the whole set,
    so states where ``f`` is near zero cannot dominate it as a per-state ratio would);
    0 for the true field, 1 for ``f_θ = 0``."""
    den = (r.f_true**2).sum()
    return ((r.f_pred - r.f_true) ** 2).sum().sqrt() / den.sqrt().clamp_min(
        torch.finfo(den.dtype).tiny
    )


def energy_drift_slope(r: Rollout, energy: Tensor | None = None) -> Tensor:
    """Least-squares slope in time of ``mean_b (E(t) − E(0)) / |E_true(0)|``, ``E`` the
    predicted energy ``r.e_pred (T, B)`` unless given: the relative drift per unit time
    (signed; with ``energy=r.e_true`` the truth's own, e.g. a measured decay)."""
    e = r.e_pred if energy is None else energy
    rel = observed_mean((e - e[:1]) / r.e_true[:1].abs().clamp_min(1e-12), 1)
    tc = r.t - r.t.mean()
    return (tc * (rel - rel.mean())).sum() / (tc * tc).sum()


def score(r: Rollout) -> dict[str, float]:
    """Every metric of a rollout, unprefixed, over the rows that did not diverge.

    - ``energy_mse``: ``mean_{t,b} (E(y_true) − E(y_pred))²`` (this and both energy
      slopes only when the DataModule has an energy);
    - ``state_mse``: ``mean_{t,b,d} (y_true − y_pred)²``;
    - ``motion_error``: see :func:`motion_error`;
    - ``valid_time``: mean over trajectories of :func:`valid_time` (threshold 0.025);
    - ``energy_drift_slope``: see :func:`energy_drift_slope`; ``true_energy_drift_slope``
      the truth's (0 for a conservative system, negative for measured friction);
    - ``conserved_drift`` (HNN): see :func:`conserved_drift`;
    - ``field_error`` (state models whose data gives ``true_field``): see
      :func:`field_error`, over every row (it is read on the true states, so a row's
      divergence does not change it); pixel models have no true field on their latents;
    - ``diverged_rows``: how many rows stopped early (the others are scored; all NaN
      if none is left);
    - state tasks: ``floor_integrator_energy_mse``, ``floor_chaos_energy_mse`` and
      their ``_state_mse`` twins (:func:`error_floors`): the part of an error that is
      not the model's;
    - pixel models also ``pixel_mse`` (decoded vs true frame pairs), ``latent_mse``
      (integrated vs encoded true pairs) and ``probe_mse``.
    """
    diverged = 0 if r.status is None else int((r.status != 0).sum())
    on_truth = {} if r.f_true is None else {"field_error": float(field_error(r))}
    if diverged:
        r = r.rows(r.status == 0)
    names = ["energy_mse", "state_mse", "motion_error", "valid_time", "energy_drift_slope"]
    names += ["true_energy_drift_slope"]
    if r.e_true is None:
        names = [n for n in names if "energy" not in n]
    if r.y_true.shape[1] == 0:
        names += ["conserved_drift"] * (r.h_pred is not None)
        return {**dict.fromkeys(names, math.nan), "diverged_rows": float(diverged), **on_truth}
    metrics = {
        "energy_mse": lambda: energy_mse_per_trajectory(r).mean(),
        "state_mse": lambda: observed_mean((r.y_true - r.y_pred) ** 2),
        "motion_error": lambda: motion_error(r.y_pred, r.y_true),
        "valid_time": lambda: valid_time(r).mean(),
        "energy_drift_slope": lambda: energy_drift_slope(r),
        "true_energy_drift_slope": lambda: energy_drift_slope(r, r.e_true),
    }
    out = {name: metrics[name]() for name in names}
    out["diverged_rows"] = diverged
    if r.h_pred is not None:
        out["conserved_drift"] = conserved_drift(r)
    out.update(on_truth)
    for key, value in (r.floors or {}).items():
        name, kind = key.rsplit("_", 1)
        out[f"floor_{name}_{kind}_mse"] = value.mean()
    if r.is_pixel:
        out["pixel_mse"] = ((r.x_pred - r.x_true) ** 2).mean()
        out["latent_mse"] = ((r.z_pred - r.z_true) ** 2).mean()
        out["probe_mse"] = r.probe_mse
    return {k: float(v) for k, v in out.items()}


def evaluate(
    model: Any, dm: Any, protocol: Protocol, probe_model: Any = None
) -> tuple[dict[str, float], Rollout]:
    """:func:`run` then :func:`score`: ``({metric: value}, rollout)``."""
    r = run(model, dm, protocol, probe_model)
    return score(r), r
