"""The two evaluation protocols of the state tasks: ``reference`` and ``clean``.

``reference`` is the published procedure (SPEC "Known quirks"), every quirk a named
field of :class:`ReferenceProtocol`, so our numbers compare with the paper's.
``clean`` avoids the quirks: the task's own energy, the held-out trajectories'
starts, a fixed horizon, per-trajectory adaptive ``dopri5`` in float64 at
``rtol = atol = 1e-9`` for every model, ground truth from the system at 1e-10.

Energy MSE of one trajectory is ``mean_t (E(y_true(t)) − E(y_pred(t)))²``; the
reported value is the mean over trajectories, and its "±" is the standard deviation
of ``n_groups`` group means (trajectories split into equal consecutive groups)
divided by ``√n_groups``, as the reference README reports it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import Tensor, nn

from hnn_pl import rollout as R
from hnn_pl.data.base import TrajectoryDataModule
from hnn_pl.integrate import scipy_odeint


@dataclass(frozen=True)
class ReferenceProtocol:
    """The published energy-MSE procedure of one task, quirks as named options.

    Attributes:
        starts: where the trajectories start. ``"box"``: each coordinate uniform in
            ``±[box_low, box_high]`` with a random sign (reference spring and
            pendulum; quirk 4: fresh random states, not test trajectories, and for
            the pendulum mostly inside the training annulus). ``"system"``: the
            system's own sampler seeded ``0 … n_starts − 1`` (n-body). ``"test"``:
            the first held-out state, over the held-out times (real pendulum).
        n_starts: number of trajectories (15 in the reference).
        box_low, box_high: the range of ``"box"`` starts.
        t_end: the horizon ``[0, t_end]`` (not used with ``"test"``).
        n_points: output times on the horizon.
        rtol: scipy RK45's ``rtol`` (quirk 3: scipy's adaptive RK45 is the
            evaluation integrator, tolerance per task).
        atol: scipy's ``atol``; ``None`` leaves scipy's default ``1e-6`` (quirk 5:
            the reference passes only ``rtol``, so ``atol`` sets the accuracy,
            ≈1e-6 instead of the stated 1e-12 or 1e-9).
        time_stretch: the models' time axis is multiplied by this factor (quirk 1:
            spring, ``1 + 0.9·noise_std = 1.09``, "to compensate for noise").
        compound_stretch: apply the stretch again on every trial: trial ``k``
            (1…15) is stretched by ``time_stretch^(k+1)`` (quirk 1: the reference
            multiplies the caller's arrays in place, so the horizon compounds; the
            exponent is chosen so that the last trial ends at t ≈ 79, as SPEC
            measured the reference).
        energy: ``"system"``, the task's energy, or ``"q2p2"``: ``q² + p²`` (quirk 2:
            the reference's pendulum evaluation compares ``q² + p²``, not its H).
        n_groups: groups for the "±".
    """

    starts: str = "box"
    n_starts: int = 15
    box_low: float = 0.2
    box_high: float = 1.0
    t_end: float = 20.0
    n_points: int = 100
    rtol: float = 1e-12
    atol: float | None = None
    time_stretch: float = 1.0
    compound_stretch: bool = False
    energy: str = "system"
    n_groups: int = 5


#: the reference protocol of each state task (SPEC, "energy-MSE protocol (reference)")
REFERENCE = {
    "spring": ReferenceProtocol(time_stretch=1.09, compound_stretch=True),
    "pendulum": ReferenceProtocol(energy="q2p2"),
    "real_pendulum": ReferenceProtocol(starts="test", n_starts=1, rtol=1e-3, n_groups=1),
    "two_body": ReferenceProtocol(starts="system", t_end=25.0, n_points=500, rtol=1e-9),
    "three_body": ReferenceProtocol(starts="system", t_end=3.0, n_points=500, rtol=1e-9),
}


@dataclass(frozen=True)
class CleanProtocol:
    """One procedure for every model: held-out starts, fixed horizon, stated solver.

    Attributes:
        t_end: horizon ``[t₀, t_end]``; ``None`` for the held-out trajectories'
            own times (the only truth the measured pendulum has).
        n_points: output times.
        max_starts: at most this many held-out starts (the first ones).
        rtol, atol: tolerances of the float64 per-trajectory ``dopri5``.
        n_groups: groups for the "±".
    """

    t_end: float | None = 20.0
    n_points: int = 200
    max_starts: int | None = None
    rtol: float = 1e-9
    atol: float = 1e-9
    n_groups: int = 5


#: the clean protocol of each state task; the rollout callback uses the same settings
CLEAN = {
    "spring": CleanProtocol(),
    "pendulum": CleanProtocol(),
    "real_pendulum": CleanProtocol(t_end=None, n_groups=1),
    "two_body": CleanProtocol(t_end=20.0, max_starts=100),
    "three_body": CleanProtocol(t_end=5.0, max_starts=100),
}


def grouped_mean(per_trajectory: Tensor, n_groups: int) -> tuple[float, float]:
    """Mean over trajectories and its "±": std of ``n_groups`` group means / √n_groups.

    With fewer trajectories than groups (or one group) the "±" is ``nan``.
    """
    x = per_trajectory.double()
    n = (len(x) // n_groups) * n_groups
    if n_groups < 2 or n == 0:
        return float(x.mean()), math.nan
    groups = x[:n].reshape(n_groups, -1).mean(1)
    return float(x.mean()), float(groups.std() / math.sqrt(n_groups))


def split_losses(field: nn.Module, x: Tensor, dx: Tensor) -> tuple[float, float]:
    """MSE of ``field(x)`` against ``dx`` over a whole split, and the reference's
    "±": std of the per-element squared errors / √(number of rows)."""
    with torch.no_grad():
        sq = (field.vector_field(None, x) - dx) ** 2
    return float(sq.mean()), float(sq.double().std() / math.sqrt(len(x)))


def _q2p2(y: Tensor) -> Tensor:
    return (y**2).sum(-1)


def _box_starts(p: ReferenceProtocol, dim: int, seed: int) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    mag = torch.rand(p.n_starts, dim, generator=g, dtype=torch.float64)
    sign = torch.randint(0, 2, (p.n_starts, dim), generator=g).double() * 2 - 1
    return sign * (p.box_low + (p.box_high - p.box_low) * mag)


def _scipy_rollout(
    f, y0: Tensor, t: Tensor, p: ReferenceProtocol, stretch: Tensor | None = None
) -> Tensor:
    """One ``solve_ivp`` RK45 call on the flattened batch; ``stretch (n,)`` scales the
    field of each trajectory, so trajectory ``k`` is read at times ``stretch_k · t``."""
    field = f
    if stretch is not None:
        c = stretch.to(torch.float64)[:, None]

        def field(s: Tensor, y: Tensor) -> Tensor:
            return c * f(s, y)

    kwargs = {"rtol": p.rtol} if p.atol is None else {"rtol": p.rtol, "atol": p.atol}
    return scipy_odeint(field, y0, t, "RK45", **kwargs)


def evaluate_reference(
    field: nn.Module, dm: TrajectoryDataModule, task: str, protocol: ReferenceProtocol | None = None
) -> dict[str, float]:
    """Energy MSE by the published procedure of ``task`` (see :data:`REFERENCE`).

    Returns:
        ``{"energy_mse", "energy_mse_pm", "n_trajectories", "t_end"}``.
    """
    p = protocol or REFERENCE[task]
    field = _float64(field)
    energy = _q2p2 if p.energy == "q2p2" else dm.energy
    if p.starts == "test":
        t, y_true = dm.test_t.double(), dm.test_y.double()
        y_pred = _scipy_rollout(field.vector_field, y_true[0], t, p)
    else:
        if p.starts == "box":
            y0 = _box_starts(p, dm.state_dim, seed=0)
        else:
            gens = [torch.Generator().manual_seed(k) for k in range(p.n_starts)]
            y0 = torch.cat([dm.system.sample_initial(1, g) for g in gens])
        t = torch.linspace(0, p.t_end, p.n_points, dtype=torch.float64)
        y_true = _scipy_rollout(dm.system.vector_field, y0, t, p)
        stretch = None
        if p.time_stretch != 1.0:
            k = torch.arange(2, p.n_starts + 2, dtype=torch.float64)
            stretch = p.time_stretch ** (k if p.compound_stretch else torch.ones_like(k))
        y_pred = _scipy_rollout(field.vector_field, y0, t, p, stretch)
    per_traj = ((energy(y_true) - energy(y_pred)) ** 2).mean(0)
    mean, pm = grouped_mean(per_traj, p.n_groups)
    return {
        "energy_mse": mean,
        "energy_mse_pm": pm,
        "n_trajectories": len(per_traj),
        "t_end": float(t[-1]),
    }


def evaluate_clean(
    field: nn.Module, dm: TrajectoryDataModule, task: str, protocol: CleanProtocol | None = None
) -> dict[str, float]:
    """Energy and state MSE by the clean procedure (see :data:`CLEAN`).

    Returns:
        ``{"energy_mse", "energy_mse_pm", "state_mse", "conserved_drift"
        (HNN only), "n_trajectories", "t_end"}``.
    """
    p = protocol or CLEAN[task]
    t, y_true = dm.rollout_target(p.t_end, p.n_points)
    if p.max_starts is not None:
        y_true = y_true[:, : p.max_starts]
    r = R.rollout(
        field,
        t,
        y_true,
        dm.energy,
        method="dopri5",
        dtype=torch.float64,
        scale_inputs=dm.x_train[:4096],
        rtol=p.rtol,
        atol=p.atol,
    )
    per_traj = ((r.e_true - r.e_pred) ** 2).mean(0)
    mean, pm = grouped_mean(per_traj, p.n_groups)
    out = {"energy_mse": mean, "energy_mse_pm": pm, "state_mse": float(R.state_mse(r))}
    if r.h_pred is not None:
        out["conserved_drift"] = float(R.conserved_drift(r))
    return {**out, "n_trajectories": y_true.shape[1], "t_end": float(t[-1])}


def evaluate(field: nn.Module, dm: TrajectoryDataModule, task: str) -> dict[str, dict]:
    """Losses and both protocols: ``{"train_loss", "train_loss_pm", "test_loss",
    "test_loss_pm", "reference": {...}, "clean": {...}}``."""
    dm.setup("test")
    train, train_pm = split_losses(field, dm.x_train, dm.dx_train)
    test, test_pm = split_losses(field, dm.x_test, dm.dx_test)
    return {
        "train_loss": train,
        "train_loss_pm": train_pm,
        "test_loss": test,
        "test_loss_pm": test_pm,
        "reference": evaluate_reference(field, dm, task),
        "clean": evaluate_clean(field, dm, task),
    }


#: how the pixel task is evaluated (it has no ODE ground truth, only gym's map)
PIXEL_PROTOCOLS = {
    "reference": "first held-out 200-frame trajectory (as the reference's early evaluation), "
    "each model with its own encoder",
    "clean": "all held-out 200-frame trajectories",
}


def evaluate_pixel(model: nn.Module, dm: TrajectoryDataModule, chunk: int = 4000) -> dict:
    """Losses and latent rollouts of a pixel model (``AutoencoderHNN`` or baseline).

    Losses are the model's three-term loss over each whole split (chunks of
    ``chunk`` rows, averaged by size). Rollouts: :class:`PixelRolloutCallback` on the
    first held-out trajectory (``reference``) and on all of them (``clean``): encode
    the first frame pair, integrate the latent ODE for 200 frames in float64
    (dopri5, rtol = atol = 1e-9), probe ``z → (θ, 0.25 θ̇)`` linearly (fit on the
    training set) and compare the energy ``1.875(1 − cos q) + p²`` with the truth.
    """
    from types import SimpleNamespace

    from hnn_pl.callbacks import PixelRolloutCallback

    dm.setup("test")
    out = {}
    with torch.no_grad():
        for split in ("train", "test"):
            x, x_next = getattr(dm, f"x_{split}"), getattr(dm, f"dx_{split}")
            total = sum(
                float(model.losses(x[i : i + chunk], x_next[i : i + chunk])["loss"])
                * len(x[i : i + chunk])
                for i in range(0, len(x), chunk)
            )
            out[f"{split}_loss"], out[f"{split}_loss_pm"] = total / len(x), math.nan
    trainer = SimpleNamespace(datamodule=dm)
    for name, max_trajectories in (("reference", 1), ("clean", None)):
        callback = PixelRolloutCallback(max_trajectories=max_trajectories, log_images=False)
        metrics, r = callback.run(trainer, model)
        out[name] = {k.split("/", 1)[1]: v for k, v in metrics.items()}
        out[name].update(n_trajectories=r.y_true.shape[1], t_end=float(r.t[-1]))
    return out


def _float64(field: nn.Module) -> nn.Module:
    import copy

    return copy.deepcopy(field).double()


def protocol_table() -> list[dict]:
    """Both protocols of every task as plain dicts (for RESULTS.md)."""
    return [
        {"task": task, "reference": asdict(REFERENCE[task]), "clean": asdict(CLEAN[task])}
        for task in REFERENCE
    ]


__all__ = [
    "REFERENCE",
    "CLEAN",
    "ReferenceProtocol",
    "CleanProtocol",
    "evaluate",
    "evaluate_reference",
    "evaluate_clean",
    "evaluate_pixel",
    "grouped_mean",
    "split_losses",
]
