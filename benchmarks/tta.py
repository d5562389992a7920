"""Time to accuracy: training seconds from the start of ``Trainer.fit`` until the HNN
first meets the joint criterion of :class:`hnn_pl.experiments.tta.TimeToAccuracy` (energy MSE
on the paper's protocol at the published value *and* clean state MSE at the paper
recipe's median, ``PAPER[task].paper_motion``), per task and recipe, over seeds
(each seed draws its own data), with 1 and 2 torch threads.

Each run is the bundled config as ``fit`` runs it (logger, checkpoints, progress bar
and rollout callbacks off) plus :class:`hnn_pl.experiments.tta.TimeToAccuracy` with
``stop=True``; the callback's own scoring is excluded from the time.
"""

from __future__ import annotations

import math
import statistics
import sys
import time

import torch
from common import main, quiet_cli, table

from hnn_pl.experiments.paper import PAPER
from hnn_pl.experiments.tta import TimeToAccuracy

TITLE = "Time to accuracy"
STATE_TASKS = ("spring", "pendulum", "real_pendulum", "two_body", "three_body")
#: the reference code's train + evaluate seconds on this kind of machine, measured by running it
REFERENCE_S = {"spring": 38.5, "pendulum": 39.1, "two_body": 55.8, "real_pendulum": 11.7}


def fit_until(task: str, recipe: str, seed: int, threads: int, max_steps=None) -> dict:
    """One HNN fit with a stopping :class:`TimeToAccuracy`: its ``reached`` and timings."""
    cli = quiet_cli(PAPER[task].config("hnn", recipe), seed, threads, max_steps)
    tta = TimeToAccuracy(task, every_n_steps=PAPER[task].tta_every[recipe], stop=True)
    cli.trainer.callbacks.append(tta)
    cli.datamodule.prepare_data()
    t0 = time.perf_counter()
    cli.trainer.fit(cli.model, cli.datamodule)
    fit_s = time.perf_counter() - t0 - tta.scoring_seconds
    last = tta.history[-1][2] if tta.history else math.nan
    return {"reached": tta.reached, "fit_s": fit_s, "steps": cli.trainer.global_step, "last": last}


def summary(runs: list[dict]) -> list[str]:
    secs = [r["reached"]["seconds"] if r["reached"] else math.inf for r in runs]
    steps = [r["reached"]["step"] if r["reached"] else math.inf for r in runs]
    ok = sum(math.isfinite(s) for s in secs)
    fmt = lambda x, f: "never" if not math.isfinite(x) else f.format(x)  # noqa: E731
    return [
        f"{ok}/{len(runs)}",
        fmt(statistics.median(secs), "{:.2f}"),
        fmt(max(secs), "{:.2f}"),
        fmt(statistics.median(steps), "{:.0f}"),
        f"{statistics.median(r['fit_s'] for r in runs):.2f}",
    ]


def run(quick: bool = False, recipes=("fast", "paper"), thread_counts=(1, 2)) -> str:
    rows = []
    for task in STATE_TASKS[:1] if quick else STATE_TASKS:
        target = f"{PAPER[task].published['hnn'].energy_mse:.3g}"
        paper = PAPER[task].paper_motion
        target += f" / {paper.state_mse:.3g}" if paper else " / —"
        for recipe in recipes:
            seeds = 1 if quick else (10 if recipe == "fast" else 3)
            if recipe == "paper" and task not in REFERENCE_S and not quick:
                continue  # no reference time to compare with; 10000 steps of 600 rows
            for threads in thread_counts[: 1 if quick else None] if recipe == "fast" else (1,):
                runs = [
                    fit_until(task, recipe, s, threads, max_steps=20 if quick else None)
                    for s in range(seeds)
                ]
                tenth = REFERENCE_S.get(task)
                ref = f"{tenth:.1f} / {tenth / 10:.2f}" if tenth else "—"
                rows.append([task, recipe, threads, target, *summary(runs), ref])
                print(rows[-1], flush=True)
    torch.set_num_threads(1)
    caption = (
        "Seeds 0…9 (fast) or 0…2 (paper; not run for three-body), each with its own data "
        "draw. Time: training seconds from `Trainer.fit`'s start (data set-up included) "
        "to the first check at or below the published HNN energy MSE on the paper's "
        "protocol and at or below the paper recipe's median clean state MSE (checks "
        "every `PAPER[task].tta_every[recipe]` optimiser steps, energy scored by "
        "float64 batched dopri5 at the protocol's tolerances, state by the clean "
        "protocol; scoring time excluded). *never*: a seed that did not reach it "
        "within the recipe's steps."
    )
    header = (
        "task | recipe | threads | energy / state target | seeds reached | median s | worst s "
        "| median steps | median fit s (until stop) | reference code train+eval s / one tenth"
    )
    return caption + "\n\n" + table(header, rows)


if __name__ == "__main__":
    main({"tta": sys.modules[__name__]}, None)
