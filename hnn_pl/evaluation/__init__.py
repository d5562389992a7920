"""Evaluating a model: protocols (how it is rolled out), views (how each kind of model is
read), metrics (how a rollout is scored), one :class:`Rollout` type.

``evaluate(model, datamodule, protocol) → (metrics, rollout)`` is the one entry point
(the rollout callback, ``predict``, ``test``, ``reproduce``); :func:`evaluate_task` adds
the losses over each split and runs every protocol a task names.
"""

from __future__ import annotations

from typing import Any

from hnn_pl import tasks
from hnn_pl.evaluation.base import Rollout, eval_mode, in_dtype, integrate_field
from hnn_pl.evaluation.contract import ObservedData, PixelData, StateData, SystemData
from hnn_pl.evaluation.metrics import (
    grouped_mean,
    motion_error,
    observed_mean,
    position_mse,
    position_valid_time,
    report,
    score,
    velocity_energy,
    velocity_energy_mse,
)
from hnn_pl.evaluation.observer import Observation, ObserverStatus, infer_starts, observe
from hnn_pl.evaluation.protocols import (
    Protocol,
    ReferenceProtocol,
    data_protocol,
    describe,
    task_protocol,
)
from hnn_pl.evaluation.reference import ReferenceCase, reference_case
from hnn_pl.evaluation.views import apply_probe, fit_probe, is_pixel_model, rollout, view_of

__all__ = [
    "ObservedData",
    "Observation",
    "ObserverStatus",
    "PixelData",
    "Protocol",
    "ReferenceCase",
    "ReferenceProtocol",
    "Rollout",
    "StateData",
    "SystemData",
    "apply_probe",
    "describe",
    "eval_mode",
    "evaluate",
    "evaluate_task",
    "fit_probe",
    "grouped_mean",
    "in_dtype",
    "infer_starts",
    "integrate_field",
    "is_pixel_model",
    "motion_error",
    "observe",
    "observed_mean",
    "position_mse",
    "position_valid_time",
    "reference_case",
    "report",
    "rollout",
    "score",
    "task_protocol",
    "data_protocol",
    "velocity_energy",
    "velocity_energy_mse",
    "view_of",
]


def evaluate(
    model: Any, datamodule: StateData, protocol: Protocol | ReferenceProtocol, **run: Any
) -> tuple[dict[str, float], Rollout]:
    """``protocol.run(model, datamodule, **run)`` then :func:`score`:
    ``({metric: value}, rollout)``."""
    r = protocol.run(model, datamodule, **run)
    return score(r), r


def evaluate_task(
    task: str,
    model: Any,
    dm: StateData,
    probe_model: Any = None,
    protocols: tuple[str, ...] = tasks.PROTOCOLS,
    losses: bool = True,
) -> dict[str, Any]:
    """The losses over each split (``train_loss``, ``test_loss`` and their "±") and the
    metrics of each of ``protocols`` that ``task`` names (``"reference"``, ``"clean"``,
    and ``"independent"`` where it has one) with :func:`report`'s, on
    ``dm`` after ``setup("test")``. ``probe_model``: the HNN whose encoder the pixel
    reference reads frames through."""
    dm.setup("test")
    out: dict[str, Any] = {}
    if losses:
        with eval_mode(model):
            out.update(view_of(model).losses(dm))
    for name in protocols:
        if getattr(tasks.get(task), name) is None:
            continue
        p = task_protocol(task, name)
        run = {"probe_model": probe_model} if name == "reference" and probe_model else {}
        metrics, r = evaluate(model, dm, p, **run)
        out[name] = {**metrics, **report(r)}
    return out
