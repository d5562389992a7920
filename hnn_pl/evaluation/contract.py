"""What evaluation reads from a DataModule, as :class:`typing.Protocol` classes.

Evaluation is duck-typed: any object with these members works, after ``setup``. The
bundled DataModules (:mod:`hnn_pl.data`) satisfy them (``tests/test_contract.py``);
:func:`problems` tells what a new one lacks, naming each member and parameter.

- :class:`StateData`: what every state protocol reads (rollout and reference).
- :class:`SystemData`: a known true system. Read where present; without it a rollout
  has no error floors, field error or energy (``has_energy``) and a reference protocol
  can only start from the held-out states (``starts="test"``).
- :class:`ObservedData`: the observed trajectories, read when a protocol infers its
  starts from observed positions (``observer_samples``, or ``observe="positions"``).
- :class:`PixelData`: what the pixel view (:class:`~hnn_pl.evaluation.views.PixelView`)
  reads: frames, their states, the probe's training data.

Also read where present, outside these: ``hparams["system"]`` (the rollout callback's
record of a run) and ``test_t0`` (a recording's file times, which ``RolloutWriter``
saves).
"""

from __future__ import annotations

import inspect
import typing
from typing import Any, Protocol, runtime_checkable

from torch import Tensor

from hnn_pl.systems.base import HamiltonianSystem


@runtime_checkable
class StateData(Protocol):
    """A state task's data: the splits, the held-out trajectories and the energy.

    Attributes:
        state_dim: ``D``, the length of a state.
        x_train, dx_train, x_test, dx_test: the derivative pairs of each split,
            ``(N, D)`` each (the losses over a split).
        test_t, test_y: the held-out trajectories, ``(T,)`` and ``(T, B, D)`` (a
            reference protocol's ``starts="test"``).
    """

    state_dim: int
    x_train: Tensor
    dx_train: Tensor
    x_test: Tensor
    dx_test: Tensor
    test_t: Tensor
    test_y: Tensor

    def setup(self, stage: str | None = None) -> None:
        """Make every member available (``evaluate_task`` calls ``setup("test")``)."""
        ...

    def rollout_target(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """``t (T,)`` and the truth ``y (T, B, D)`` of the held-out trajectories: as held
        (``t_end=None``) or on ``n_points`` times to ``t_end``; ``NaN`` where a
        trajectory was not observed. Its first row gives the rollout's starts."""
        ...

    def energy(self, y: Tensor) -> Tensor:
        """The physical energy of states ``(..., D) -> (...)`` that the metrics compare."""
        ...

    def reference_inputs(self, n: int | None = None) -> Tensor:
        """``n`` training inputs ``(n, D)`` (all for ``None``): the states over which the
        spread of a learned ``H_θ`` is measured."""
        ...


@runtime_checkable
class SystemData(StateData, Protocol):
    """State data with a known true system.

    Attributes:
        system: a :class:`~hnn_pl.systems.base.HamiltonianSystem` or ``None``: its
            ``vector_field`` and ``trajectory`` make the error floors, the reference
            protocol's truth and the observer floor; ``sample_initial`` its
            ``starts="system"``; ``energy_qv`` the energy from positions and velocities.
        has_energy: whether :meth:`energy` is defined (else no energy is scored).
    """

    system: HamiltonianSystem | None
    has_energy: bool

    def true_field(self, t: Tensor, y: Tensor) -> Tensor | None:
        """The true ``dy/dt`` at held-out states ``y (T, B, D)`` at times ``t (T,)``, or
        ``None`` (no truth: no field error)."""
        ...


@runtime_checkable
class ObservedData(StateData, Protocol):
    """State data with observed trajectories, the flat tables of the held-out split.

    Attributes:
        observe: ``"states"`` or ``"positions"`` (the tables hold ``q`` alone, and a
            rollout protocol infers its starts from them).
        obs_y_test, obs_t_test, obs_traj_test: the held-out samples ``(S, D)`` (or
            ``(S, D/2)`` positions), their times ``(S,)`` and trajectory ids ``(S,)``
            int64, trajectory by trajectory.
        data: the served tensors by name, the ``obs_*`` tables before any thinning
            (read first where present), or ``None``.
    """

    observe: str
    obs_y_test: Tensor
    obs_t_test: Tensor
    obs_traj_test: Tensor
    data: dict[str, Tensor] | None


@runtime_checkable
class PixelData(StateData, Protocol):
    """The pixel task's data: frame pairs, their ``(θ, θ̇)`` states and the canonical map.

    The pixel view reads ``setup``, the splits (frame pairs ``(N, 2·size²)``, the next
    pair as ``dx``) and these.

    Attributes:
        rollout_frames: the stored length of a held-out rollout, in frames.
    """

    rollout_frames: int

    def rollout_truth(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """``t (T,)``, states ``(T, B, 2)`` and frame pairs ``(T, B, 2·size²)`` of the
        held-out trajectories over ``n_points`` frames (or to ``t_end``)."""
        ...

    def trajectory_truth(
        self, theta0: float, omega0: float, n: int
    ) -> tuple[Tensor, Tensor, Tensor]:
        """As :meth:`rollout_truth`, ``B = 1``, for a fresh trajectory from ``(θ₀, θ̇₀)``
        over ``n`` frames."""
        ...

    def probe_data(self, n: int | None = None) -> tuple[Tensor, Tensor]:
        """``n`` training inputs ``(n, 2·size²)`` (all for ``None``) and their canonical
        ``(q, p) (n, 2)``: what the linear probe ``z ↦ (q, p)`` is fitted on."""
        ...

    def canonical(self, y: Tensor) -> Tensor:
        """``(θ, θ̇) (..., 2) -> (q, p) (..., 2)``."""
        ...

    def canonical_energy(self, qp: Tensor, energy_coef: float | None = None) -> Tensor:
        """The energy of canonical states ``(..., 2) -> (...)`` with coefficient
        ``energy_coef`` (``None``: the data's)."""
        ...


def members(proto: type) -> dict[str, Any]:
    """The members ``proto`` and its protocol bases declare: name → the method, or the
    annotated type of an attribute."""
    out: dict[str, Any] = {}
    hints = typing.get_type_hints(proto)
    for cls in reversed(proto.__mro__):
        if cls is Protocol or not getattr(cls, "_is_protocol", False):
            continue
        out |= {k: hints[k] for k in vars(cls).get("__annotations__", {})}
        out |= {
            k: v for k, v in vars(cls).items() if inspect.isfunction(v) and not k.startswith("_")
        }
    return out


def _signature_problems(name: str, want: Any, got: Any) -> list[str]:
    """Where ``got`` (a bound method) cannot be called as ``want`` (the protocol's) is:
    the same leading parameter names in order, a default wherever ``want`` has one,
    and defaults for any parameter beyond."""
    try:
        params = list(inspect.signature(got).parameters.values())
    except (TypeError, ValueError):
        return [f"{name}: no inspectable signature"]
    wanted = list(inspect.signature(want).parameters.values())[1:]
    names = [p.name for p in wanted]
    if [p.name for p in params[: len(wanted)]] != names:
        return [f"{name}{inspect.signature(got)}: its parameters must begin {names}"]
    out = [
        f"{name}: parameter {p.name!r} needs a default"
        for p, w in zip(params, wanted)
        if w.default is not inspect.Parameter.empty and p.default is inspect.Parameter.empty
    ]
    extra = params[len(wanted) :]
    return out + [
        f"{name}: extra parameter {p.name!r} needs a default"
        for p in extra
        if p.default is inspect.Parameter.empty and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    ]


def problems(dm: Any, proto: type) -> list[str]:
    """Why ``dm`` does not satisfy ``proto``, one line per member (empty: it does):
    a missing member, a method whose parameters are not the protocol's (names in
    order; defaults where it has them), or an attribute of another type."""
    out = []
    for name, want in members(proto).items():
        if not hasattr(dm, name):
            out.append(f"{name}: missing")
        elif inspect.isfunction(want):
            got = getattr(dm, name)
            if not callable(got):
                out.append(f"{name}: not callable")
            else:
                out += _signature_problems(name, want, got)
        else:
            try:
                ok = isinstance(getattr(dm, name), want)
            except TypeError:  # a parameterised generic: presence only
                ok = True
            if not ok:
                kind = getattr(want, "__name__", want)
                out.append(f"{name}: {type(getattr(dm, name)).__name__}, not {kind}")
    return out
