"""How each kind of model is read: the only place that tells state and pixel models apart.

A view wraps a model and answers the questions a protocol asks of it: how a start is
encoded and a state decoded, what the truth of a held-out rollout is, how the
rollout is read (a state model's states are its own; a pixel model's latents go
through a linear probe to ``(q, p)``), how its losses over a split are computed.
:func:`view_of` picks the view; :func:`rollout` (``hnn_pl.rollout``) integrates any
model from given starts through it.

Duck-typed, public attributes only. A model: ``field`` (a module with
``vector_field(t, y)`` and, for an HNN, ``hamiltonian(y)``) or is one itself; pixel
models also ``encode``, ``decode``, ``frame_dt``, ``losses``. A DataModule: the
protocols of :mod:`hnn_pl.evaluation.contract` (:class:`StateData`, read where present
:class:`SystemData` and :class:`ObservedData`; pixel ones :class:`PixelData`).
"""

from __future__ import annotations

import inspect
import json
import math
from typing import Any

import torch
from torch import Tensor

from hnn_pl.evaluation.base import Rollout, eval_mode, integrate_field, learned_h
from hnn_pl.evaluation.contract import ObservedData, PixelData, StateData
from hnn_pl.evaluation.metrics import (
    energy_mse_of,
    h_spread,
    mse,
    split_loss,
    state_mse_per_trajectory,
    velocity_energy,
)
from hnn_pl.integrate import odeint

#: size of the start perturbation that measures the chaos floor
CHAOS_EPS = 1e-4
#: error floors kept (:func:`error_floors`): they are the true system's, the same for
#: every model and every periodic rollout of a fit
FLOORS_KEPT = 64
_FLOORS: dict[str, dict[str, Tensor]] = {}


def is_pixel_model(model: Any) -> bool:
    """Whether ``model`` works on observations through ``encode``/``decode``."""
    return callable(getattr(model, "encode", None)) and callable(getattr(model, "decode", None))


def _device(model: Any) -> torch.device:
    param = next(model.parameters(), None)
    return param.device if param is not None else torch.device("cpu")


class StateView:
    """A model of ``dy/dt`` on states (``HNN``, ``Baseline``, any ``vector_field``)."""

    def __init__(self, model: Any) -> None:
        self.model, self.field = model, getattr(model, "field", model)

    def encode(self, y: Tensor) -> Tensor:
        return y

    def decode(self, z: Tensor) -> Tensor | None:
        return None

    def times(self, t_end: float | None, n_points: int | None) -> Tensor:
        """Output times of a rollout from given starts: ``linspace(0, t_end, n_points)``."""
        return torch.linspace(0.0, t_end or 1.0, n_points or 100, dtype=torch.float64)

    def energy(self, dm: StateData) -> Any:
        """The physical energy of the states, or ``None``."""
        return dm.energy if getattr(dm, "has_energy", True) else None

    def start_width(self, dm: StateData) -> int:
        """The width of a start: the data's ``state_dim``."""
        return int(dm.state_dim)

    def starts(self, dm: StateData) -> Tensor:
        """The held-out starts ``(B, D)``."""
        return dm.rollout_target()[1][0]

    def losses(self, dm: StateData) -> dict[str, float]:
        """MSE of ``f_θ`` against the split's targets (:func:`split_loss`), train and test."""
        out = {}
        for split in ("train", "test"):
            x, dx = getattr(dm, f"x_{split}"), getattr(dm, f"dx_{split}")
            out[f"{split}_loss"], out[f"{split}_loss_pm"] = split_loss(self.field, x, dx)
        return out

    def run(self, p: Any, dm: StateData, reader: Any = None, floors: bool = True) -> Rollout:
        """Roll out from ``dm.rollout_target(t_end, n_points)``'s starts under ``p``."""
        device = _device(self.model)
        t, y_true = rollout_target(dm, p)
        y_true = y_true[:, : p.max_starts].to(device)
        n_obs = observer_samples(p, dm)
        y0 = y_true[0] if n_obs is None else observed_starts(self.model, dm, n_obs, p)
        y0 = y0[: y_true.shape[1]].to(device)
        sol, field = integrate_field(
            self.field, y0, t.to(device), dtype=p.dtype, **p.solver_kwargs()
        )
        y_pred = sol.y
        y_true = y_true.to(y_pred.dtype)
        energy = self.energy(dm)
        r = Rollout(t.to(y_pred.dtype), y_true, y_pred, status=sol.status, t_stop=sol.t_stop)
        r.n_groups = p.n_groups
        if n_obs is not None:
            r.positions = y_true.shape[-1] // 2
        if energy is not None:
            r.e_true = energy(y_true)
            r.e_pred = (
                energy(y_pred) if n_obs is None else velocity_energy(dm.system, field, y_pred)
            )
        r.h_pred = learned_h(field, y_pred)
        if r.h_pred is not None:
            r.h_scale = h_spread(field, dm.reference_inputs(p.scale_rows).to(y_pred))
        if floors:
            r.floors = error_floors(dm, r.t, y_true, p)
            if n_obs is not None and r.floors:
                r.floors["observer_position"] = observer_floor(dm, r.t, y_true, n_obs, p)
        f_true = dm.true_field(r.t, y_true) if callable(getattr(dm, "true_field", None)) else None
        if f_true is not None and n_obs is None:  # a field in another gauge has no true twin
            r.f_true = f_true.to(y_pred)
            r.f_pred = field.vector_field(None, y_true.flatten(0, 1)).reshape(y_true.shape)
        return r


def rollout_target(dm: StateData, p: Any) -> tuple[Tensor, Tensor]:
    """``dm.rollout_target(p.t_end, p.n_points)``, asking for the protocol's first
    ``p.max_starts`` starts alone where the data's ``rollout_target`` takes ``max_starts``
    (the bundled simulated data: no truth is integrated that is not scored)."""
    if p.max_starts is not None and "max_starts" in inspect.signature(dm.rollout_target).parameters:
        return dm.rollout_target(p.t_end, p.n_points, max_starts=p.max_starts)
    return dm.rollout_target(p.t_end, p.n_points)


def observer_samples(p: Any, dm: StateData) -> int | None:
    """The observed positions a protocol's starts are inferred from: its
    ``observer_samples``, else ``POSITION_SAMPLES`` for data of positions alone, else
    ``None`` (the true starts)."""
    from hnn_pl.evaluation.observer import POSITION_SAMPLES

    n = getattr(p, "observer_samples", None)
    if n is None and getattr(dm, "observe", "states") == "positions":
        n = POSITION_SAMPLES
    return n


def observed_starts(model: Any, dm: ObservedData, n: int, p: Any) -> Tensor:
    """Each held-out trajectory's start ``(B, 2k)`` float64 inferred by
    :func:`~hnn_pl.evaluation.observer.infer_starts` from the first ``n`` observed
    positions of its trajectory (``dm``'s ``obs_*_test`` tables as observed, before any
    thinning: the held-out trajectory's first samples, noise included), in the field's
    own gauge, its momentum search bounded by
    :func:`~hnn_pl.evaluation.observer.training_momentum_bound` (a trained model's).
    Trajectories shorter than ``n`` give all their samples (``M`` = the shortest)."""
    from hnn_pl.evaluation.observer import infer_starts, training_momentum_bound

    raw = getattr(dm, "data", None) or {}
    q, t, traj = (
        raw.get(f"obs_{k}_test", getattr(dm, f"obs_{k}_test")) for k in ("y", "t", "traj")
    )
    k = int(dm.state_dim) // 2
    counts = torch.bincount(traj)
    m = int(min(n, int(counts.min())))
    first = torch.cumsum(counts, 0) - counts
    rows = first[:, None] + torch.arange(m)
    bound = training_momentum_bound(model, dm)
    q0 = q[rows][..., :k].double()
    return infer_starts(model, t[rows].double(), q0, method="rk4", p_bound=bound)


def observer_floor(dm: ObservedData, t: Tensor, y_true: Tensor, n: int, p: Any) -> Tensor:
    """The position error the observer leaves with the true field, per trajectory
    ``(B,)``: ``mean_{t,i<k} (q(t) − q_true(t))²`` of the true system from the starts
    :func:`observed_starts` infers with the true field (``dm.system``) from the same
    ``n`` noisy positions: what no model can beat under this protocol."""
    from hnn_pl.evaluation.metrics import position_mse_per_trajectory

    y0 = observed_starts(dm.system, dm, n, p)[: y_true.shape[1]]
    y = dm.system.trajectory(y0.to(torch.float64), t.to(torch.float64))
    return position_mse_per_trajectory(y, y_true.double(), y_true.shape[-1] // 2)


def error_floors(dm: StateData, t: Tensor, y_true: Tensor, p: Any) -> dict[str, Tensor]:
    """How much of a rollout's error is not the model's, per trajectory ``(B,)``:

    - ``integrator``: the true system (``dm.system``) through the protocol's own method,
      step and tolerances, against the truth;
    - ``chaos``: the true system at truth accuracy from starts perturbed by
      ``CHAOS_EPS · N(0, 1)`` (a fixed draw), against the truth: the error any model
      inherits from sensitivity to its start.

    Each as energy MSE and state MSE over time (``{name}_energy``, ``{name}_state``).
    Empty without ``dm.system`` or an energy. They depend on no model: the last
    :data:`FLOORS_KEPT` are kept (keyed by the system, the protocol and the values of
    ``t`` and ``y_true``), so a fit's periodic rollouts compute them once.
    """
    system = getattr(dm, "system", None)
    if system is None or not getattr(dm, "has_energy", True):
        return {}
    key = _floors_key(dm, system, t, y_true, p)
    if key not in _FLOORS:
        if len(_FLOORS) >= FLOORS_KEPT:
            del _FLOORS[next(iter(_FLOORS))]
        _FLOORS[key] = _error_floors(dm, system, t, y_true, p)
    return dict(_FLOORS[key])


def _floors_key(dm: StateData, system: Any, t: Tensor, y_true: Tensor, p: Any) -> str:
    """What :func:`error_floors` depends on: the data's class (its ``energy``), the
    system (class, parameters, a user system's source), the protocol, and the values
    of ``t`` and ``y_true``."""
    from hnn_pl.data.base import tensors_digest
    from hnn_pl.systems.base import source_digest, system_spec

    spec = system_spec(system) | {"source": source_digest(type(system))}
    spec |= {"data": f"{type(dm).__module__}.{type(dm).__qualname__}", "protocol": repr(p)}
    spec["values"] = tensors_digest({"t": t, "y_true": y_true})
    return json.dumps(spec, sort_keys=True, default=repr)


def _error_floors(
    dm: StateData, system: Any, t: Tensor, y_true: Tensor, p: Any
) -> dict[str, Tensor]:
    y0, tt = y_true[0].double(), t.double()
    kw = {k: v for k, v in p.solver_kwargs().items() if k != "method"}
    integ = odeint(system.vector_field, y0, tt, p.method, return_status=True, **kw).y
    gen = torch.Generator().manual_seed(0)
    noise = torch.randn(y0.shape, generator=gen, dtype=torch.float64).to(y0.device)
    chaos = system.trajectory(y0 + CHAOS_EPS * noise, tt)
    e_true, out = dm.energy(y_true.double()), {}
    for name, y in (("integrator", integ), ("chaos", chaos)):
        out[f"{name}_energy"] = energy_mse_of(e_true, dm.energy(y))
        out[f"{name}_state"] = state_mse_per_trajectory(y_true.double(), y)
    return out


def fit_probe(z: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """Affine least squares ``target (N, K) ≈ [z, 1] @ W`` for ``z (N, L)``, in float64:
    ``W (L + 1, K)`` and the mean squared residual (:func:`~hnn_pl.evaluation.metrics.mse`)."""
    a = torch.cat([z.double(), z.new_ones(len(z), 1, dtype=torch.float64)], -1)
    w = torch.linalg.lstsq(a, target.double()).solution
    return w, mse(a @ w, target.double())


def apply_probe(w: Tensor, z: Tensor) -> Tensor:
    """``[z, 1] @ W``: ``(..., L) -> (..., K)`` in float64."""
    return z.double() @ w[:-1] + w[-1]


class PixelView(StateView):
    """An autoencoder with latent dynamics (``AutoencoderHNN``, ``AutoencoderBaseline``):
    starts are frame pairs, rollouts are decoded, and read by a linear probe."""

    def encode(self, x: Tensor) -> Tensor:
        return self.model.encode(x)

    def decode(self, z: Tensor) -> Tensor:
        param = next(self.model.parameters(), None)
        return self.model.decode(z if param is None else z.to(param.dtype))

    def times(self, t_end: float | None, n_points: int | None) -> Tensor:
        """``n_points`` frames (200 by default) in the latent field's time unit."""
        return torch.arange(n_points or 200, dtype=torch.float64) * self.model.frame_dt

    def energy(self, dm: PixelData) -> None:
        return None

    def start_width(self, dm: PixelData) -> int:
        """The width of a start: a frame pair, the model's ``input_dim``."""
        return int(self.model.hparams["input_dim"])

    def starts(self, dm: PixelData) -> Tensor:
        """The held-out trajectories' first frame pairs ``(B, input_dim)``."""
        return dm.rollout_truth(n_points=2)[2][0]

    def losses(self, dm: PixelData, chunk: int = 4000) -> dict[str, float]:
        """The model's three-term loss over each whole split (chunks averaged by size)."""
        out = {}
        for split in ("train", "test"):
            x, x_next = getattr(dm, f"x_{split}"), getattr(dm, f"dx_{split}")
            total = sum(
                float(self.model.losses(x[i : i + chunk], x_next[i : i + chunk])["loss"])
                * len(x[i : i + chunk])
                for i in range(0, len(x), chunk)
            )
            out[f"{split}_loss"], out[f"{split}_loss_pm"] = total / len(x), math.nan
        return out

    def run(self, p: Any, dm: PixelData, reader: Any = None, floors: bool = True) -> Rollout:
        """Encode each held-out trajectory's first frame pair (or ``p.start``'s), integrate
        the latent field over ``n_points`` frames (``[0, model_t_end]`` if given),
        decode, and read ``(q, p)`` by an affine probe fitted on ``probe_rows`` encoded
        training inputs — through ``reader``'s encoder (another model's: the reference's
        evaluation of the baseline through the HNN's encoder) or the model's own."""
        model, reader = self.model, reader or self.model
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
        sol, field = integrate_field(
            model.field, z_true[0], t_model * model.frame_dt, dtype=p.dtype, **p.solver_kwargs()
        )
        z_pred = sol.y
        x_pred = model.decode(z_pred.to(z_true.dtype))
        if not p.reencode and reader is not model:
            raise ValueError(
                "a probe on another model's encoder reads decoded frames: reencode=True"
            )
        z_read = reader.encode(x_pred) if p.reencode else z_pred
        qp_true = dm.canonical(y_true.to(device)).double()
        qp_pred = apply_probe(probe, z_read)
        r = Rollout(t.double().cpu(), qp_true, qp_pred, status=sol.status, t_stop=sol.t_stop)
        r.e_true = dm.canonical_energy(qp_true, p.energy_coef)
        r.e_pred = dm.canonical_energy(qp_pred, p.energy_coef)
        r.z_true, r.z_pred, r.x_true, r.x_pred = z_true.to(z_pred.dtype), z_pred, x_true, x_pred
        r.probe, r.probe_mse, r.n_groups = probe, probe_mse, p.n_groups
        r.h_pred = learned_h(field, z_pred)
        if r.h_pred is not None:
            z_own = z_train if reader is model else model.encode(x_train.to(device))
            r.h_scale = h_spread(field, z_own.to(z_pred.dtype))
        return r


def view_of(model: Any) -> StateView:
    """The view of ``model``: :class:`PixelView` for a model with ``encode``/``decode``."""
    return PixelView(model) if is_pixel_model(model) else StateView(model)


def rollout(
    model: Any,
    y0: Tensor,
    t: Tensor,
    method: str = "dopri5",
    dtype: str | torch.dtype | None = "float64",
    energy: Any = None,
    encode: bool = True,
    **kwargs: Any,
) -> Rollout:
    """Integrate a model from given starts: ``hnn_pl.rollout(model, y0, t, method=…)``.

    Args:
        model: a state model (``HNN``, ``Baseline``), a pixel model (``AutoencoderHNN``,
            ``AutoencoderBaseline``), or any module with ``vector_field(t, y)``.
        y0: ``(B, D)`` starts; for a pixel model ``(B, input_dim)`` frame pairs,
            encoded first.
        t: ``(T,)`` output times (pixel models: in the latent field's time unit, one
            frame lasting ``model.frame_dt``).
        method: a key of :data:`hnn_pl.integrate.METHODS`.
        dtype: integrate a copy of the field in this dtype (``"model"``: as is).
        energy: optional ``(..., D) -> (...)`` physical energy of the states.
        encode: ``False``: ``y0`` are a pixel model's latents already.
        **kwargs: ``rtol``, ``atol``, ``step_size``, ``options`` of :func:`hnn_pl.odeint`.

    Returns:
        a :class:`Rollout` without truth: ``y_pred (T, B, D)`` (pixel: latents, also
        ``z_pred``), ``h_pred`` (HNN), ``e_pred`` (with ``energy``), ``x_pred`` decoded
        frames (pixel), ``status`` and ``t_stop``.
    """
    view = view_of(model)
    with eval_mode(model):
        z0 = view.encode(y0) if encode else y0
        t = torch.as_tensor(t)
        sol, field = integrate_field(view.field, z0, t, dtype, method=method, **kwargs)
        y = sol.y
        out = Rollout(t.to(y.dtype), None, y, status=sol.status, t_stop=sol.t_stop)
        out.h_pred = learned_h(field, y)
        out.x_pred = view.decode(y)
        if out.x_pred is not None:
            out.z_pred = y
        if energy is not None:
            out.e_pred = energy(y)
    return out
