"""The fast recipes scored in the true energy: the independent evaluation of issue 9.

The spring and pendulum fast configs (HNN and baseline twin), seeds 0-9, each seed its
own data draw, scored by the published procedure without its quirks:
``ReferenceProtocol(atol=1e-12)`` (15 starts with each coordinate in ±[0.2, 1], scipy
RK45 at rtol = atol = 1e-12 on a float64 copy of the model, 100 points on t ∈ [0, 20],
no time stretch, the system's true energy: q² + p² and 3(1 − cos q) + p²). Beside
them the paper's protocol (with its quirks), and the reference code's HNN trained on
this machine and scored the same way (from issue 9), as the bar.
"""

from __future__ import annotations

import statistics
import sys

from common import main, quiet_cli, table

from hnn_pl.evaluation import ReferenceProtocol, evaluate, task_protocol
from hnn_pl.experiments.paper import PAPER

TITLE = "Independent evaluation (true energy)"
INDEPENDENT = ReferenceProtocol(atol=1e-12)
#: the reference code's HNN, three seeds on its own data draws, this evaluation (issue 9)
REFERENCE_CODE = {"spring": (2.3e-4, 3.3e-4, 8.6e-4), "pendulum": (5.5e-4, 5.5e-4, 7.0e-4)}


def run(quick: bool = False) -> str:
    rows = []
    for task in ("spring",) if quick else ("spring", "pendulum"):
        bar = min(REFERENCE_CODE[task])
        for model in ("hnn", "baseline"):
            indep, paper = [], []
            for seed in range(1 if quick else 10):
                cli = quiet_cli(PAPER[task].config(model, "fast"), seed, 1, 20 if quick else None)
                cli.trainer.fit(cli.model, cli.datamodule)
                indep.append(evaluate(cli.model, cli.datamodule, INDEPENDENT)[0])
                paper.append(
                    evaluate(cli.model, cli.datamodule, task_protocol(task, "reference"))[0]
                )
            e = [r["energy_mse"] for r in indep]
            p = [r["energy_mse"] for r in paper]
            rows.append(
                [
                    task,
                    model,
                    f"{statistics.median(e):.2e}",
                    f"{max(e):.2e}",
                    f"{sum(x <= bar for x in e)}/{len(e)}",
                    ", ".join(f"{x:.1e}" for x in e),
                    f"{statistics.median(p):.2e} ({max(p):.2e})",
                ]
            )
            print(rows[-1], flush=True)
    bars = "; ".join(f"{t}: " + ", ".join(f"{x:.1e}" for x in v) for t, v in REFERENCE_CODE.items())
    head = (
        "task | model | median | worst | seeds ≤ the reference code's best | per seed 0…9 "
        "| paper's protocol, median (worst)"
    )
    return (
        table(head, rows)
        + f"\n\nThe reference code's HNN on its own three data draws, same evaluation: {bars}."
    )


if __name__ == "__main__":
    main({"independent": sys.modules[__name__]}, None)
