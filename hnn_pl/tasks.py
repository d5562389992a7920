"""The task registry: each experiment of the paper named once, as plain data.

A :class:`Task` holds what is *about the experiment* rather than about a model or a
data set: its configs (per recipe and model), the published numbers and its protocols
(:class:`Spec`: built by :func:`hnn_pl.evaluation.task_protocol`). Imports nothing of
the package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

MODELS = ("baseline", "hnn", "dissipative")
RECIPES = ("paper", "fast", "traj")
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


class Published(NamedTuple):
    """The reference README's numbers of one model on one task (SPEC)."""

    train_loss: float
    test_loss: float
    energy_mse: float
    energy_mse_pm: float


class PaperMotion(NamedTuple):
    """The paper recipe's HNN on the clean protocol, median over seeds: the motion a
    fast recipe must match (the state half of time to accuracy). ``source``: the
    run that measured it."""

    state_mse: float
    field_error: float
    source: str


@dataclass(frozen=True)
class Task:
    """One experiment of the paper.

    Attributes:
        name: the registry key, also the stem of its configs.
        title: a human name.
        kind: ``"state"`` (models of ``dy/dt`` on states) or ``"pixel"`` (an
            autoencoder with latent dynamics; its latent field has no true field).
        published: model name → :class:`Published`.
        reference: the published energy-MSE procedure (scipy's for state tasks; a
            latent rollout of one trajectory for the pixel task).
        clean: the protocol every model is scored with the same way, and the
            rollout callback's default.
        cost: relative training time (``reproduce`` starts the longest first).
        tta_every: recipe → optimiser steps between time-to-accuracy checks.
        models: the models with bundled configs (``reproduce`` trains these).
        paper_motion: the paper recipe's HNN medians on the clean protocol
            (:class:`PaperMotion`), the state target of
            :class:`~hnn_pl.commands.tta.TimeToAccuracy`; ``None``: no state target.
        traj_models: the models with a trajectory-objective config (recipe
            ``"traj"``: ``TASK_traj.yaml``, learning from the observed states only).
        independent: the true-energy evaluation (the published procedure without its
            quirks, ``atol=1e-12``) where it applies, or ``None``.
        default: whether ``reproduce`` runs it without ``--tasks``.
        has_true_field: whether the clean protocol scores a field error (a pixel
            model's latent field has no true counterpart).
    """

    name: str
    title: str
    kind: str
    published: dict[str, Published]
    reference: Spec
    clean: Spec
    cost: float = 1.0
    tta_every: dict[str, int] = field(default_factory=lambda: {"paper": 50, "fast": 10, "traj": 50})
    models: tuple[str, ...] = ("baseline", "hnn")
    paper_motion: PaperMotion | None = None
    traj_models: tuple[str, ...] = ()
    independent: Spec | None = None
    default: bool = True
    has_true_field: bool = True

    def models_for(self, recipe: str) -> tuple[str, ...]:
        """The models with a bundled config of ``recipe``."""
        return self.traj_models if recipe == "traj" else self.models

    def config(self, model: str = "hnn", recipe: str = "paper") -> str:
        """The bundled config's file name, e.g. ``spring_fast_baseline.yaml``."""
        if recipe not in RECIPES or model not in self.models_for(recipe):
            raise ValueError(
                f"recipe must be in {RECIPES} and model in {self.models_for(recipe)} "
                f"(the {recipe!r} configs of {self.name})"
            )
        parts = [self.name, "" if recipe == "paper" else recipe, model * (model != "hnn")]
        return "_".join(p for p in parts if p) + ".yaml"


#: where the ``paper_motion`` medians come from (issue 21)
_PAPER = "paper recipe HNN (TASK.yaml), clean protocol: medians of seeds 0-9 (RESULTS.md)"

TASKS: dict[str, Task] = {
    t.name: t
    for t in (
        Task(
            "spring",
            "ideal mass-spring",
            "state",
            {
                "baseline": Published(3.7134e-02, 3.6656e-02, 1.7077e-01, 2.06e-02),
                "hnn": Published(3.6933e-02, 3.5928e-02, 3.8416e-04, 6.53e-05),
            },
            reference(time_stretch=1.09, compound_stretch=True),
            rollout(),
            cost=1.0,
            paper_motion=PaperMotion(1.359e-01, 5.243e-02, _PAPER),
            traj_models=("baseline", "hnn"),
            independent=reference(atol=1e-12),
        ),
        Task(
            "pendulum",
            "ideal pendulum",
            "state",
            {
                "baseline": Published(3.2606e-02, 3.5273e-02, 4.1519e-02, 9.62e-03),
                "hnn": Published(3.2787e-02, 3.5586e-02, 2.4852e-02, 5.42e-03),
            },
            reference(energy="q2p2"),
            rollout(),
            cost=1.2,
            paper_motion=PaperMotion(9.599e-02, 1.630e-02, _PAPER),
            traj_models=("baseline", "hnn"),
            independent=reference(atol=1e-12),
        ),
        Task(
            "real_pendulum",
            "real pendulum (measured)",
            "state",
            {
                "baseline": Published(2.7455e-03, 2.1864e-03, 3.8564e-01, 6.92e-02),
                "hnn": Published(9.2376e-03, 5.9584e-03, 1.4477e-02, 4.65e-03),
            },
            reference(starts="test", n_starts=1, rtol=1e-3, n_groups=1),
            rollout(t_end=None, n_points=None, n_groups=1),
            cost=0.8,
            models=("baseline", "hnn", "dissipative"),
            traj_models=("baseline", "hnn", "dissipative"),
            paper_motion=PaperMotion(8.393e-03, 4.075e-02, _PAPER),
        ),
        Task(
            "two_body",
            "two-body",
            "state",
            {
                "baseline": Published(3.2682e-05, 2.9575e-05, 6.3276e-02, 3.36e-02),
                "hnn": Published(2.9959e-06, 2.8218e-06, 3.8751e-05, 5.04e-06),
            },
            reference(starts="system", t_end=25.0, n_points=500, rtol=1e-9),
            rollout(t_end=20.0, max_starts=100),
            cost=4.0,
            tta_every={"paper": 250, "fast": 50, "traj": 100},
            paper_motion=PaperMotion(
                3.897e-03, 7.364e-03, _PAPER + " (field error: the 9 seeds that record it)"
            ),
            traj_models=("baseline", "hnn"),
        ),
        Task(
            "three_body",
            "three-body",
            "state",
            {
                "baseline": Published(9.5573e-02, 3.8000e-01, 1.0906e02, 7.74e01),
                "hnn": Published(8.0346e-02, 4.8809e-01, 4.1926e-02, 3.39e-02),
            },
            reference(starts="system", t_end=3.0, n_points=500, rtol=1e-9),
            rollout(t_end=5.0, max_starts=100),
            cost=5.0,
            tta_every={"paper": 250, "fast": 150},
            paper_motion=PaperMotion(8.989e-02, 4.879e-01, _PAPER),
        ),
        Task(
            "pixel",
            "pixel pendulum",
            "pixel",
            {
                "baseline": Published(1.7731e-04, 1.7306e-04, 9.2748e-03, 1.14e-03),
                "hnn": Published(1.8683e-04, 1.8451e-04, 1.5315e-04, 8.42e-06),
            },
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
            cost=4.5,
            tta_every={"paper": 500, "fast": 250},
            default=False,
            has_true_field=False,
        ),
    )
}

#: what ``reproduce`` runs without ``--tasks`` (the pixel task adds ~5 min per run)
DEFAULT_TASKS = [name for name, t in TASKS.items() if t.default]
#: the tasks with trajectory-objective configs (``reproduce --recipe traj``)
TRAJ_TASKS = [name for name, t in TASKS.items() if t.traj_models]


def get(name: str) -> Task:
    """The task called ``name``.

    Raises:
        KeyError: naming the known tasks.
    """
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {', '.join(TASKS)}")
    return TASKS[name]
