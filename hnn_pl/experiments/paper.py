"""The paper's table as data: for each of its tasks the published numbers, the bundled
configs that make its rows, what a run costs and the targets of time to accuracy.

Keyed by the task's name in :data:`hnn_pl.tasks.TASKS` (the library's registry, which
holds a task's protocols). A new system or model is added here only when it joins the
paper's table. Imports nothing of the package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

MODELS = ("baseline", "hnn", "dissipative")
RECIPES = ("paper", "fast", "traj")


class Published(NamedTuple):
    """The reference README's numbers of one model on one task."""

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
class PaperTask:
    """One task of the paper's table.

    Attributes:
        name: the task (a key of :data:`hnn_pl.tasks.TASKS`), also the stem of its
            configs.
        published: model name → :class:`Published`.
        cost: relative training time (``reproduce`` starts the longest first).
        tta_every: recipe → optimiser steps between time-to-accuracy checks.
        models: the models with bundled configs (``reproduce`` trains these).
        paper_motion: the paper recipe's HNN medians on the clean protocol
            (:class:`PaperMotion`), the state target of
            :class:`~hnn_pl.experiments.tta.TimeToAccuracy`; ``None``: no state target.
        traj_models: the models with a trajectory-objective config (recipe
            ``"traj"``: ``TASK_traj.yaml``, learning from the observed states only).
        default: whether ``reproduce`` runs it without ``--tasks``.
        has_true_field: whether the clean protocol scores a field error (a pixel
            model's latent field has no true counterpart).
    """

    name: str
    published: dict[str, Published]
    cost: float = 1.0
    tta_every: dict[str, int] = field(default_factory=lambda: {"paper": 50, "fast": 10, "traj": 50})
    models: tuple[str, ...] = ("baseline", "hnn")
    paper_motion: PaperMotion | None = None
    traj_models: tuple[str, ...] = ()
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

PAPER: dict[str, PaperTask] = {
    t.name: t
    for t in (
        PaperTask(
            "spring",
            {
                "baseline": Published(3.7134e-02, 3.6656e-02, 1.7077e-01, 2.06e-02),
                "hnn": Published(3.6933e-02, 3.5928e-02, 3.8416e-04, 6.53e-05),
            },
            cost=1.0,
            paper_motion=PaperMotion(1.359e-01, 5.243e-02, _PAPER),
            traj_models=("baseline", "hnn"),
        ),
        PaperTask(
            "pendulum",
            {
                "baseline": Published(3.2606e-02, 3.5273e-02, 4.1519e-02, 9.62e-03),
                "hnn": Published(3.2787e-02, 3.5586e-02, 2.4852e-02, 5.42e-03),
            },
            cost=1.2,
            paper_motion=PaperMotion(9.599e-02, 1.630e-02, _PAPER),
            traj_models=("baseline", "hnn"),
        ),
        PaperTask(
            "real_pendulum",
            {
                "baseline": Published(2.7455e-03, 2.1864e-03, 3.8564e-01, 6.92e-02),
                "hnn": Published(9.2376e-03, 5.9584e-03, 1.4477e-02, 4.65e-03),
            },
            cost=0.8,
            models=("baseline", "hnn", "dissipative"),
            traj_models=("baseline", "hnn", "dissipative"),
            paper_motion=PaperMotion(8.393e-03, 4.075e-02, _PAPER),
        ),
        PaperTask(
            "two_body",
            {
                "baseline": Published(3.2682e-05, 2.9575e-05, 6.3276e-02, 3.36e-02),
                "hnn": Published(2.9959e-06, 2.8218e-06, 3.8751e-05, 5.04e-06),
            },
            cost=4.0,
            tta_every={"paper": 250, "fast": 50, "traj": 100},
            paper_motion=PaperMotion(
                3.897e-03, 7.364e-03, _PAPER + " (field error: the 9 seeds that record it)"
            ),
            traj_models=("baseline", "hnn"),
        ),
        PaperTask(
            "three_body",
            {
                "baseline": Published(9.5573e-02, 3.8000e-01, 1.0906e02, 7.74e01),
                "hnn": Published(8.0346e-02, 4.8809e-01, 4.1926e-02, 3.39e-02),
            },
            cost=5.0,
            tta_every={"paper": 250, "fast": 150},
            paper_motion=PaperMotion(8.989e-02, 4.879e-01, _PAPER),
        ),
        PaperTask(
            "pixel",
            {
                "baseline": Published(1.7731e-04, 1.7306e-04, 9.2748e-03, 1.14e-03),
                "hnn": Published(1.8683e-04, 1.8451e-04, 1.5315e-04, 8.42e-06),
            },
            cost=4.5,
            tta_every={"paper": 500, "fast": 250},
            default=False,
            has_true_field=False,
        ),
    )
}

#: what ``reproduce`` runs without ``--tasks`` (the pixel task adds ~5 min per run)
DEFAULT_TASKS = [name for name, t in PAPER.items() if t.default]
#: the tasks with trajectory-objective configs (``reproduce --recipe traj``)
TRAJ_TASKS = [name for name, t in PAPER.items() if t.traj_models]


def get(name: str) -> PaperTask:
    """The paper's task called ``name``.

    Raises:
        KeyError: naming the known tasks.
    """
    if name not in PAPER:
        raise KeyError(f"unknown task {name!r}; known tasks: {', '.join(PAPER)}")
    return PAPER[name]


def jobs(
    names: list[str], models: list[str], recipe: str, seeds: range
) -> list[tuple[str, str, int]]:
    """Every ``(task, model, seed)`` of ``names × models × seeds`` whose model has a
    bundled ``recipe`` config, the costliest tasks first (then by seed, model)."""
    found = [
        (t, m, s) for t in names for m in models if m in get(t).models_for(recipe) for s in seeds
    ]
    return sorted(found, key=lambda j: (-get(j[0]).cost, j[2], j[1]))
