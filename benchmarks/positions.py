"""Positions only (issue 32, item 6): the position-only recipe's training cost beside the
states-only recipe's, on the same task and draw, in one run, 1 thread.

Per task (spring, pendulum) and seed (0; ``HNN_PL_POSITIONS_SEEDS=0,1`` for more): the HNN
of ``TASK_positions.yaml`` (the momenta withheld, learned) and of ``TASK_traj.yaml`` (the
states-only trajectory recipe), each trained by its bundled recipe as ``fit`` runs it
(logger, checkpoints, callbacks off), then scored through the same observer (starts from
the first 15 observed positions of each held-out trajectory, the clean protocol): the
training seconds, the optimiser steps, the seconds per step, the position MSE, and the
ratios positions / states of the training time and of the step cost.

Time to accuracy: every ``CHECK`` steps the same observer protocol scores the model
(:class:`PositionCheck`, its scoring excluded from the time); the target is twice the
states recipe's final position MSE on the same draw (the issue's "≤ 2× the
states-only recipe's"), and a run's time is its first check at or below it.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import torch
from common import main, ms, quiet_cli, table
from lightning.pytorch import Callback

from hnn_pl.evaluation import eval_mode, evaluate, score, task_protocol
from hnn_pl.evaluation.observer import POSITION_SAMPLES

TITLE = "Positions only"
SEEDS = tuple(int(s) for s in os.environ.get("HNN_PL_POSITIONS_SEEDS", "0").split(","))
RECIPES = {"states": "{task}_traj.yaml", "positions": "{task}_positions.yaml"}
#: optimiser steps between the time-to-accuracy checks
CHECK = 100


class PositionCheck(Callback):
    """Every ``every`` optimiser steps, the observer protocol's position MSE:
    :attr:`history` of ``(step, training seconds since fit start without the checks,
    position MSE)``."""

    def __init__(self, task: str, every: int) -> None:
        self.protocol = task_protocol(task, "clean", {"observer_samples": POSITION_SAMPLES})
        self.every, self.history, self.scoring = every, [], 0.0

    def on_fit_start(self, trainer, pl_module) -> None:
        self._run = self.protocol.prepare(trainer.datamodule)
        self._start, self.scoring = time.perf_counter(), 0.0

    def on_train_batch_end(self, trainer, pl_module, *args) -> None:
        step = trainer.global_step
        if step % self.every:
            return
        t0 = time.perf_counter()
        with eval_mode(pl_module):
            mse = float(score(self._run(pl_module))["position_mse"])
        self.history.append((step, t0 - self._start - self.scoring, mse))
        self.scoring += time.perf_counter() - t0


def reached(history: list, target: float) -> float:
    """The training seconds of the first check at or below ``target`` (inf: none)."""
    return next((sec for _, sec, mse in history if mse <= target), float("inf"))


def train(task: str, recipe: str, seed: int, quick: bool) -> dict:
    """One recipe's HNN trained and scored: ``train_s`` (checks excluded), ``steps``,
    ``position_mse``, ``history`` (:class:`PositionCheck`)."""
    cli = quiet_cli(RECIPES[recipe].format(task=task), seed, 1, 20 if quick else None)
    check = PositionCheck(task, 20 if quick else CHECK)
    cli.trainer.callbacks.append(check)
    cli.datamodule.prepare_data()
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    cli.trainer.fit(cli.model, cli.datamodule)
    train_s = time.perf_counter() - t0 - check.scoring
    protocol = task_protocol(task, "clean", {"observer_samples": POSITION_SAMPLES})
    metrics, _ = evaluate(cli.model, cli.datamodule, protocol)
    steps = cli.trainer.global_step
    record = {"train_s": train_s, "steps": steps, "position_mse": metrics["position_mse"]}
    return {**record, "history": check.history}


def run(quick: bool = False) -> str:
    rows = []
    for task in ("pendulum",) if quick else ("spring", "pendulum"):  # quick: every code path
        runs = {r: [train(task, r, s, quick) for s in SEEDS] for r in RECIPES}
        for state, position in zip(runs["states"], runs["positions"], strict=True):
            target = 2 * state["position_mse"]
            for run in (state, position):
                run["tta_s"] = reached(run["history"], target)
        keys = ("train_s", "steps", "position_mse", "tta_s")
        med = {r: {k: statistics.median(x[k] for x in v) for k in keys} for r, v in runs.items()}
        per_step = {r: m["train_s"] / m["steps"] for r, m in med.items()}
        for r, m in med.items():
            ratio = ""
            if r == "positions":
                ratio = " / ".join(
                    f"{a / b:.2f}"
                    for a, b in (
                        (m["train_s"], med["states"]["train_s"]),
                        (per_step[r], per_step["states"]),
                        (m["tta_s"], med["states"]["tta_s"]),
                    )
                )
            cells = [task, r, RECIPES[r].format(task=task), f"{m['steps']:.0f}"]
            cells += [f"{m['train_s']:.1f}", ms(per_step[r]), f"{m['position_mse']:.3g}"]
            cells += [f"{m['tta_s']:.1f}", ratio]
            rows.append(cells)
            print(rows[-1], flush=True)
    caption = (
        f"Seeds {', '.join(map(str, SEEDS))} (median), 1 thread, one run; each recipe as "
        "bundled (its own steps, windows and batches), the same draw for both. Position "
        "MSE: through the observer (15 samples), the clean protocol, to t = 20. Time to "
        f"accuracy: training seconds to the first check (every {CHECK} steps, scoring "
        "excluded) at or below twice the states recipe's final position MSE; inf: never."
    )
    header = (
        "task | data | config | steps | train s | ms per step | position MSE "
        "| s to 2× states' MSE | positions / states: train s / step cost / time to accuracy"
    )
    return caption + "\n\n" + table(header, rows)


if __name__ == "__main__":
    main({"positions": sys.modules[__name__]}, None)
