"""Evaluating a trained model on its task: losses, the reference and the clean protocol.

``reference`` is the published procedure (SPEC "Known quirks"), every quirk a named
field of :class:`~hnn_pl.protocols.ReferenceProtocol`, so our numbers compare with
the paper's; it runs scipy's RK45 on the flattened batch (:func:`evaluate_reference`).
``clean`` is the task's :class:`~hnn_pl.protocols.Protocol` run by the rollout
engine (:func:`hnn_pl.rollouts.evaluate`), the same code the rollout callback runs.
Each task's protocols are defined once, in :mod:`hnn_pl.tasks`.

Energy MSE of one trajectory is ``mean_t (E(y_true(t)) − E(y_pred(t)))²``; the
reported value is the mean over trajectories, and its "±" is the standard deviation
of ``n_groups`` group means (trajectories split into equal consecutive groups)
divided by ``√n_groups``, as the reference README reports it.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl import rollouts, tasks
from hnn_pl.integrate import odeint, scipy_odeint
from hnn_pl.protocols import Protocol, ReferenceProtocol


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


def _field64(model: Any) -> nn.Module:
    return copy.deepcopy(getattr(model, "field", model)).double()


@dataclass
class ReferenceCase:
    """A :class:`ReferenceProtocol`'s trajectories, made once, scored often: ``t (T,)``
    float64, starts ``y0 (n, D)``, truth ``y_true (T, n, D)``, the models' time factors
    ``stretch (n,)`` (quirk 1) or ``None``, the compared ``energy (..., D) -> (...)``,
    and ``y_read (T, n, D)``: the truth at the times the models' states are read
    (``stretch_k · t``; ``y_true`` itself without a stretch), for the state error."""

    protocol: ReferenceProtocol
    t: Tensor
    y0: Tensor
    y_true: Tensor
    stretch: Tensor | None
    energy: Callable[[Tensor], Tensor]
    y_read: Tensor | None = None

    def __post_init__(self) -> None:
        if self.y_read is None:
            self.y_read = self.y_true


def reference_case(dm: Any, protocol: ReferenceProtocol) -> ReferenceCase:
    """Starts, times and truth of ``protocol`` on ``dm``'s system (scipy RK45 truth)."""
    p = protocol
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
    stretch = None
    if p.time_stretch != 1.0:
        k = torch.arange(2, p.n_starts + 2, dtype=torch.float64)
        stretch = p.time_stretch ** (k if p.compound_stretch else torch.ones_like(k))
        y_read = _scipy_rollout(dm.system.vector_field, y0, t, p, stretch)
        return ReferenceCase(p, t, y0, y_true, stretch, energy, y_read)
    return ReferenceCase(p, t, y0, y_true, stretch, energy)


def score_reference(model: Any, case: ReferenceCase, solver: str = "scipy") -> dict[str, float]:
    """Energy MSE of ``model`` on a prepared case (a float64 copy of its field).

    ``solver="scipy"`` is the published procedure (RK45 on the flattened batch);
    ``"torch"`` integrates the same starts, stretch and horizon with the batched
    per-trajectory ``dopri5`` at the protocol's ``rtol`` and ``atol`` (scipy's default
    1e-6 where the protocol leaves it unset): the same ≈1e-6 accuracy, several
    times cheaper, for scoring during training. Besides the published numbers:
    :func:`hnn_pl.rollouts.motion_error` against the truth at the times the states
    are read (an energy MSE alone cannot tell a field that has learned the motion
    from one that barely moves).
    """
    p = case.protocol
    f = _field64(model).vector_field
    if solver == "torch":
        atol = 1e-6 if p.atol is None else p.atol
        y0, field = case.y0, f
        if case.stretch is not None:  # carry each row's factor as a constant coordinate

            def field(s: Tensor, yc: Tensor) -> Tensor:
                return torch.cat([yc[:, -1:] * f(s, yc[:, :-1]), torch.zeros_like(yc[:, -1:])], -1)

            y0 = torch.cat([case.y0, case.stretch[:, None]], -1)
        with torch.no_grad():
            sol = odeint(field, y0, case.t, "dopri5", p.rtol, atol, return_status=True)
        if not bool(sol.ok.all()):  # a diverging model is as far from the target as can be
            return {"energy_mse": math.inf, "motion_error": math.inf, "t_end": float(case.t[-1])}
        y_pred = sol.y[..., : case.y0.shape[-1]]
    elif solver == "scipy":
        y_pred = _scipy_rollout(f, case.y0, case.t, p, case.stretch)
    else:
        raise ValueError(f"solver must be 'scipy' or 'torch', got {solver!r}")
    per_traj = ((case.energy(case.y_true) - case.energy(y_pred)) ** 2).mean(0)
    mean, pm = grouped_mean(per_traj, p.n_groups)
    return {
        "energy_mse": mean,
        "energy_mse_pm": pm,
        "n_trajectories": len(per_traj),
        "t_end": float(case.t[-1]),
        "motion_error": float(rollouts.motion_error(y_pred, case.y_read)),
    }


def evaluate_reference(
    model: Any, dm: Any, task: str, protocol: ReferenceProtocol | None = None
) -> dict[str, float]:
    """Energy MSE of ``model`` (any module with ``vector_field``) by the published
    procedure of state ``task`` (or ``protocol``) on ``dm`` after ``setup``:
    ``{"energy_mse", "energy_mse_pm", "n_trajectories", "t_end"}``."""
    return score_reference(model, reference_case(dm, protocol or tasks.get(task).reference))


def evaluate_protocol(
    model: Any, dm: Any, protocol: Protocol, probe_model: Any = None
) -> dict[str, float]:
    """:func:`hnn_pl.rollouts.score`'s metrics under ``protocol`` (pixel: ``probe_model``,
    see :func:`hnn_pl.rollouts.run`) plus the grouped ``energy_mse_pm``,
    ``n_trajectories`` and ``t_end``."""
    metrics, r = rollouts.evaluate(model, dm, protocol, probe_model)
    if r.e_true is not None:
        per_traj = rollouts.energy_mse_per_trajectory(r.rows(r.status == 0))
        metrics["energy_mse_pm"] = grouped_mean(per_traj, protocol.n_groups)[1]
    return {**metrics, "n_trajectories": r.y_true.shape[1], "t_end": float(r.t[-1])}


def evaluate_state(task: tasks.Task, model: Any, dm: Any) -> dict[str, Any]:
    """Losses over each split and both protocols of a state task: ``{"train_loss",
    "train_loss_pm", "test_loss", "test_loss_pm", "reference": {…}, "clean": {…}}``,
    and ``"independent": {…}`` (the true-energy evaluation) where the task has one."""
    dm.setup("test")
    field = getattr(model, "field", model)
    train, train_pm = split_losses(field, dm.x_train, dm.dx_train)
    test, test_pm = split_losses(field, dm.x_test, dm.dx_test)
    extra = {}
    if task.independent is not None:
        extra["independent"] = evaluate_reference(model, dm, task.name, task.independent)
    return {
        **extra,
        "train_loss": train,
        "train_loss_pm": train_pm,
        "test_loss": test,
        "test_loss_pm": test_pm,
        "reference": evaluate_reference(model, dm, task.name),
        "clean": evaluate_protocol(model, dm, task.clean),
    }


def evaluate_pixel(
    task: tasks.Task, model: Any, dm: Any, chunk: int = 4000, probe_model: Any = None
) -> dict[str, Any]:
    """Losses and both latent-rollout protocols of a pixel model (``probe_model``: the
    HNN whose encoder the reference protocol reads the model's frames through; ``None``:
    the model's own).

    Losses are the model's three-term loss over each whole split (chunks of
    ``chunk`` rows, averaged by size).
    """
    dm.setup("test")
    out: dict[str, Any] = {}
    with torch.no_grad():
        for split in ("train", "test"):
            x, x_next = getattr(dm, f"x_{split}"), getattr(dm, f"dx_{split}")
            total = sum(
                float(model.losses(x[i : i + chunk], x_next[i : i + chunk])["loss"])
                * len(x[i : i + chunk])
                for i in range(0, len(x), chunk)
            )
            out[f"{split}_loss"], out[f"{split}_loss_pm"] = total / len(x), math.nan
    out["reference"] = evaluate_protocol(model, dm, task.reference, probe_model)
    out["clean"] = evaluate_protocol(model, dm, task.clean)
    return out


#: task kind -> its evaluation (read by :meth:`hnn_pl.tasks.Task.evaluate`)
EVALUATORS = {"state": evaluate_state, "pixel": evaluate_pixel}


def evaluate(model: Any, dm: Any, task: str) -> dict[str, Any]:
    """Losses and both protocols of ``model`` on ``task`` (any kind)."""
    return tasks.get(task).evaluate(model, dm)
