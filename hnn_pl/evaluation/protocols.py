"""How a model is rolled out: the two kinds of protocol, each with ``run(model, dm) →
Rollout`` (and ``prepare(dm)``: the truth made once, a model rolled out often).

A :class:`Protocol` rolls a model out from held-out starts with :func:`hnn_pl.odeint`
through the model's view (the rollout callback, ``predict``, the clean evaluation; the
pixel task's reference); a :class:`ReferenceProtocol` is the published procedure of a
state task with each of the reference code's quirks a named field, scipy's RK45 on the
flattened batch. Each task names its protocols as data (:mod:`hnn_pl.tasks`);
:func:`task_protocol` builds them, and a config overrides fields, never restates them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import Any

from hnn_pl import tasks
from hnn_pl.evaluation.base import Rollout, eval_mode
from hnn_pl.evaluation.contract import StateData
from hnn_pl.evaluation.reference import reference_case
from hnn_pl.evaluation.views import view_of
from hnn_pl.integrate import METHODS


class _Fields:
    def replace(self, **overrides: Any) -> Any:
        """A copy with ``overrides`` (unknown names raise ``TypeError``)."""
        return dataclasses.replace(self, **overrides)


@dataclass(frozen=True)
class Protocol(_Fields):
    """A batched rollout of a model from held-out starts, and how it is scored.

    Attributes:
        t_end: horizon of the system's ground truth; ``None``: the held-out
            trajectories' own times (measured data) or ``n_points`` frames (pixel).
        n_points: output times (pixel: frames); ``None`` keeps the stored length.
        max_starts: at most this many held-out starts (the first ones).
        method, rtol, atol, step_size: the integrator (:func:`hnn_pl.odeint`).
        dtype: ``"float64"`` integrates a float64 copy of the field (the rollout's
            error stays far below the model's); ``"model"``: the model's dtype.
        n_groups: groups for the "±" (std of group means / √n_groups).
        scale_rows: training inputs over which ``H_θ``'s spread (the yardstick of
            ``conserved_drift``) is measured.
        probe_rows: pixel: training inputs the probe ``z ↦ (q, p)`` is fitted on.
        start: pixel: ``(θ₀, θ̇₀)`` of one fresh trajectory to roll out instead of the
            held-out ones (its first frame dropped, as the training samples').
        model_t_end: pixel: the latent integration spans ``[0, model_t_end]`` frames at
            the ``n_points`` output times, read against the true frames ``0 … n_points
            − 1``; ``None``: one point per frame.
        energy_coef: pixel: ``α`` of the scored energy ``α(1 − cos q) + p²``; ``None``:
            the data's.
        reencode: pixel: decode the rollout and encode the frames again before the
            probe (else the probe reads the integrated latents).
        probe_encoder: pixel: ``"own"``, or ``"hnn"``: the probe is fitted on, and the
            decoded frames re-encoded by, the encoder of an HNN passed to
            :meth:`Protocol.run` (``probe_model``; the model's own without one).
        observer_samples: state models: infer each start from the first
            ``observer_samples`` observed (noisy) positions of its held-out trajectory
            (:func:`~hnn_pl.evaluation.observer.observe`) instead of taking the true
            state, and score what is invariant under the momenta's gauge: positions
            and the true energy from ``(q, q̇)``; ``None``: the true start, or
            :data:`~hnn_pl.evaluation.observer.POSITION_SAMPLES` when the data observe
            positions alone.
    """

    t_end: float | None = 20.0
    n_points: int | None = 200
    max_starts: int | None = None
    method: str = "dopri5"
    rtol: float = 1e-9
    atol: float = 1e-9
    step_size: float | None = None
    dtype: str = "float64"
    n_groups: int = 5
    scale_rows: int = 4096
    probe_rows: int | None = None
    start: tuple[float, float] | None = None
    model_t_end: float | None = None
    energy_coef: float | None = None
    reencode: bool = False
    probe_encoder: str = "own"
    observer_samples: int | None = None

    def __post_init__(self) -> None:
        check_fields(self)
        if self.probe_encoder not in ("own", "hnn"):
            raise ValueError(f"probe_encoder must be 'own' or 'hnn', got {self.probe_encoder!r}")
        if self.probe_encoder == "hnn" and not self.reencode:
            raise ValueError("probe_encoder='hnn' reads decoded frames: it needs reencode=True")
        if self.start is not None:
            if len(self.start) != 2:
                raise ValueError(f"start must be (theta0, omega0), got {self.start!r}")
            object.__setattr__(self, "start", tuple(float(v) for v in self.start))
        if self.dtype not in ("float64", "float32", "model"):
            raise ValueError(f"dtype must be 'float64', 'float32' or 'model', got {self.dtype!r}")
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; valid methods: {sorted(METHODS)}")

    def solver_kwargs(self) -> dict[str, Any]:
        """``method``, ``rtol``, ``atol``, ``step_size`` for :func:`hnn_pl.odeint`."""
        return {k: getattr(self, k) for k in ("method", "rtol", "atol", "step_size")}

    def run(
        self, model: Any, dm: StateData, probe_model: Any = None, floors: bool = True
    ) -> Rollout:
        """Roll ``model`` out from ``dm``'s held-out starts (see the model's view,
        :mod:`hnn_pl.evaluation.views`). ``probe_model``: with ``probe_encoder="hnn"``,
        the HNN whose encoder reads a pixel model's frames. ``floors=False`` skips the
        true system's own rollouts (:func:`~hnn_pl.evaluation.views.error_floors`).
        The models are put in eval mode and restored."""
        reader = probe_model if self.probe_encoder == "hnn" else None
        with eval_mode(model, reader):
            return view_of(model).run(self, dm, reader, floors)

    def prepare(self, dm: StateData, solver: str = "torch") -> Any:
        """``model ↦ Rollout`` on ``dm`` without the error floors (time to accuracy);
        ``solver``: a rollout protocol always integrates with its own ``method``."""
        return lambda model: self.run(model, dm, floors=False)


#: scipy's default ``atol``, which sets a reference protocol's accuracy when it leaves
#: ``atol`` unset (quirk 5)
SCIPY_ATOL = 1e-6


@dataclass(frozen=True)
class ReferenceProtocol(_Fields):
    """The published energy-MSE procedure of one state task, quirks as named options.

    Attributes:
        starts: ``"box"``: each coordinate uniform in ``±[box_low, box_high]``, random
            sign (spring, pendulum; quirk 4); ``"system"``: the system's sampler
            seeded ``0 … n_starts − 1`` (n-body); ``"test"``: the first held-out
            state over the held-out times (real pendulum).
        n_starts, t_end, n_points: trajectories, horizon ``[0, t_end]``, output times.
        box_low, box_high: the range of ``"box"`` starts.
        rtol, atol: scipy RK45's (quirk 3); ``atol=None`` leaves scipy's 1e-6, which
            then sets the accuracy (quirk 5).
        time_stretch: factor on the models' time axis (quirk 1: spring, 1.09).
        compound_stretch: trial ``k`` (1…15) stretched by ``time_stretch^(k+1)``
            (quirk 1: in-place mutation; the horizon compounds to t ≈ 79).
        energy: ``"system"`` or ``"q2p2"``: ``q² + p²`` (quirk 2, pendulum).
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

    #: a reference rollout is float64 (the field's copy), at the protocol's tolerances
    dtype = "float64"

    def solver_kwargs(self) -> dict[str, Any]:
        """dopri5 at ``rtol`` and ``atol`` (scipy's 1e-6 where unset), for given starts."""
        return {
            "method": "dopri5",
            "rtol": self.rtol,
            "atol": SCIPY_ATOL if self.atol is None else self.atol,
        }

    def run(self, model: Any, dm: StateData, solver: str = "scipy") -> Rollout:
        """The published procedure on ``dm``'s system (see :meth:`ReferenceCase.run
        <hnn_pl.evaluation.reference.ReferenceCase.run>`)."""
        return self.prepare(dm, solver)(model)

    def prepare(self, dm: StateData, solver: str = "scipy") -> Any:
        """``model ↦ Rollout`` on starts and truth made once."""
        case = reference_case(dm, self)
        return lambda model: case.run(model, solver)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.starts not in ("box", "system", "test"):
            raise ValueError(f"starts must be 'box', 'system' or 'test', got {self.starts!r}")
        if self.energy not in ("system", "q2p2"):
            raise ValueError(f"energy must be 'system' or 'q2p2', got {self.energy!r}")


def check_fields(p: Any) -> None:
    """Counts positive, tolerances non-negative and finite, ``n_groups ≥ 1``.

    Raises:
        ValueError: naming the field and the value.
    """
    for f in fields(p):
        v = getattr(p, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        if not math.isfinite(v):
            raise ValueError(f"{type(p).__name__}.{f.name} must be finite, got {v}")
        if f.name in ("rtol", "atol") and v < 0:
            raise ValueError(f"{type(p).__name__}.{f.name} must be >= 0, got {v}")
        if f.name not in ("rtol", "atol", "box_low") and v <= 0:
            raise ValueError(f"{type(p).__name__}.{f.name} must be > 0, got {v}")


def describe(p: Protocol | ReferenceProtocol) -> str:
    """The fields that differ from the class's defaults, ``"k=v, …"`` (or the defaults)."""
    default = type(p)()
    changed = [
        f"{f.name}={getattr(p, f.name)}"
        for f in fields(p)
        if getattr(p, f.name) != getattr(default, f.name)
    ]
    base = ", ".join(f"{f.name}={getattr(default, f.name)}" for f in fields(p))
    return ", ".join(changed) or f"defaults ({base})"


#: a task's protocol spec kind → its class (:class:`hnn_pl.tasks.Spec`)
KINDS = {"rollout": Protocol, "reference": ReferenceProtocol}


def build(spec: tasks.Spec) -> Protocol | ReferenceProtocol:
    """The protocol a :class:`~hnn_pl.tasks.Spec` describes."""
    return KINDS[spec.kind](**spec.fields)


def task_protocol(
    task: str, name: str = "clean", overrides: dict[str, Any] | None = None
) -> Protocol | ReferenceProtocol:
    """Task ``task``'s protocol ``name`` (``"clean"``, ``"reference"``, ``"independent"``)
    with ``overrides``, checked now (``ValueError`` naming an unknown task, protocol or
    field, or a bad value)."""
    try:
        spec = getattr(tasks.get(task), name) if name in tasks.PROTOCOLS else None
    except KeyError as e:
        raise ValueError(e.args[0]) from None
    if spec is None:
        raise ValueError(f"task {task!r} has no protocol {name!r}; known: {tasks.PROTOCOLS}")
    try:
        return build(spec).replace(**(overrides or {}))
    except TypeError as e:
        raise ValueError(f"overrides {overrides}: {e}") from None


def data_protocol(
    datamodule: Any, name: str = "clean", overrides: dict[str, Any] | None = None
) -> Protocol | ReferenceProtocol:
    """The protocol ``name`` of the task ``datamodule`` holds the data of
    (:data:`hnn_pl.tasks.DATA_TASKS`: by its class, else by its system's unless it is a
    recording). Data of no task has only a ``"clean"`` protocol: a recording's
    :data:`hnn_pl.tasks.RECORDED`, else the default rollout."""
    recorded = getattr(datamodule, "recording", None) is not None
    system = None if recorded else getattr(datamodule, "system", None)
    for cls in (type(datamodule), type(system)):
        if cls.__name__ in tasks.DATA_TASKS:
            return task_protocol(tasks.DATA_TASKS[cls.__name__], name, overrides)
    if name != "clean":
        raise ValueError(
            f"{type(datamodule).__name__} holds no task's data: only the clean protocol "
            f"applies, got {name!r}; name a task"
        )
    spec = tasks.RECORDED if recorded else tasks.rollout()
    try:
        return build(spec).replace(**(overrides or {}))
    except TypeError as e:
        raise ValueError(f"overrides {overrides}: {e}") from None
