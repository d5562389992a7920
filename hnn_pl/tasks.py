"""The task registry: each experiment named once, as plain data.

A :class:`Task` holds what the library needs to score a model on an experiment: its
kind and its protocols (:class:`Spec`: built by :func:`hnn_pl.evaluation.task_protocol`).
What makes a task a row of the paper's table (published numbers, configs, costs, time
to accuracy targets) is :mod:`hnn_pl.experiments.paper`. Imports nothing of the package.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

#: the protocols a task may name
PROTOCOLS = ("clean", "reference", "independent")


class Spec(NamedTuple):
    """A protocol as data: ``kind`` ``"rollout"`` (:class:`hnn_pl.evaluation.Protocol`)
    or ``"reference"`` (:class:`hnn_pl.evaluation.ReferenceProtocol`) and the fields that
    differ from the class's defaults."""

    kind: str
    fields: dict[str, Any]


def rollout(**fields: Any) -> Spec:
    return Spec("rollout", fields)


def reference(**fields: Any) -> Spec:
    return Spec("reference", fields)


@dataclass(frozen=True)
class Task:
    """One experiment: what the library needs to score a model on it.

    Attributes:
        name: the registry key, also the stem of its configs.
        title: a human name.
        kind: ``"state"`` (models of ``dy/dt`` on states) or ``"pixel"`` (an
            autoencoder with latent dynamics; its latent field has no true field).
        reference: the published procedure (the energy MSE by scipy for the HNN paper's
            state tasks; a latent rollout of one trajectory for the pixel task; for the
            chain pendulums a rollout of the model in its dtype at the constrained-HNN
            code's tolerance 1e-7 over the test set's 3 s, which
            :meth:`~hnn_pl.data.chain_pendulum.ChainPendulumData.rollout_errors` scores).
        clean: the protocol every model is scored with the same way, and the
            rollout callback's default.
        independent: the true-energy evaluation (the published procedure without its
            quirks, ``atol=1e-12``) where it applies, or ``None``.
    """

    name: str
    title: str
    kind: str
    reference: Spec
    clean: Spec
    independent: Spec | None = None


#: the clean protocol of recorded data: the held-out trajectories as recorded (there is
#: no truth off the samples), one group
RECORDED = rollout(t_end=None, n_points=None, n_groups=1)

TASKS: dict[str, Task] = {
    t.name: t
    for t in (
        Task(
            "spring",
            "ideal mass-spring",
            "state",
            reference(time_stretch=1.09, compound_stretch=True),
            rollout(),
            independent=reference(atol=1e-12),
        ),
        Task(
            "pendulum",
            "ideal pendulum",
            "state",
            reference(energy="q2p2"),
            rollout(),
            independent=reference(atol=1e-12),
        ),
        Task(
            "real_pendulum",
            "real pendulum (measured)",
            "state",
            reference(starts="test", n_starts=1, rtol=1e-3, n_groups=1),
            RECORDED,
        ),
        Task(
            "two_body",
            "two-body",
            "state",
            reference(starts="system", t_end=25.0, n_points=500, rtol=1e-9),
            rollout(t_end=20.0, max_starts=100),
        ),
        Task(
            "three_body",
            "three-body",
            "state",
            reference(starts="system", t_end=3.0, n_points=500, rtol=1e-9),
            rollout(t_end=5.0, max_starts=100),
        ),
        Task(
            "pixel",
            "pixel pendulum",
            "pixel",
            rollout(
                t_end=None,
                n_points=200,
                n_groups=1,
                start=(0.2934, 0.7326),
                model_t_end=0.98 * 200,
                energy_coef=1.9,
                reencode=True,
                probe_encoder="hnn",
            ),
            rollout(t_end=None, n_points=200),
        ),
        *(
            Task(
                f"chain{n}",
                f"{n}-link chain pendulum (constrained-HNN benchmark)",
                "state",
                rollout(t_end=None, n_points=None, rtol=1e-7, atol=1e-9, dtype="model"),
                rollout(t_end=None, n_points=None),
            )
            for n in (2, 3)
        ),
    )
}


#: the task of the bundled data, by the class name of its DataModule or of its system
DATA_TASKS = {
    "RealPendulumData": "real_pendulum",
    "PixelPendulumData": "pixel",
    "MassSpring": "spring",
    "Pendulum": "pendulum",
    "TwoBody": "two_body",
    "ThreeBody": "three_body",
}


def get(name: str) -> Task:
    """The task called ``name``.

    Raises:
        KeyError: naming the known tasks.
    """
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {', '.join(TASKS)}")
    return TASKS[name]
