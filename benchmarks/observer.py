"""The observer's cost: starts inferred from the first 15 noisy angles (the first second)
of the 25 held-out trajectories of the paper's pendulum draw (seed 0, σ = 0.1), with the
exact pendulum field and with an HNN trained by ``pendulum_positions.yaml`` (its 600
steps; ``--quick``: 20), 1 thread, the median of repeated calls
(:func:`hnn_pl.evaluation.observer.observe` with its defaults, as the evaluation calls it).
"""

from __future__ import annotations

import statistics
import sys
import time

import torch
from common import main, quiet_cli, table

from hnn_pl.evaluation.observer import POSITION_SAMPLES, observe

TITLE = "Observer: 25 starts from positions"
REPEATS = 7


def held_out_windows(dm) -> tuple[torch.Tensor, torch.Tensor]:
    """The first :data:`POSITION_SAMPLES` observed angles of each held-out trajectory:
    ``t (B, M)``, ``q (B, M, 1)`` float64."""
    q, t, traj = dm.obs_y_test, dm.obs_t_test, dm.obs_traj_test
    counts = torch.bincount(traj)
    rows = (torch.cumsum(counts, 0) - counts)[:, None] + torch.arange(POSITION_SAMPLES)
    return t[rows].double(), q[rows][..., :1].double()


def timed(field, t: torch.Tensor, q: torch.Tensor, repeats: int) -> list:
    """One row: median and fastest seconds of ``observe`` over ``repeats`` calls (after one
    warm-up), its LM iterations and the mean position residual."""
    observe(field, t, q)
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        o = observe(field, t, q)
        seconds.append(time.perf_counter() - t0)
    return [
        len(q),
        f"{statistics.median(seconds):.3f}",
        f"{min(seconds):.3f}",
        o.iterations,
        f"{float(o.rms.mean()):.4f}",
        f"{int(o.ok.sum())}/{len(q)}",
    ]


def run(quick: bool = False) -> str:
    cli = quiet_cli("pendulum_positions.yaml", 0, 1, 20 if quick else None)
    dm = cli.datamodule
    dm.prepare_data()
    torch.set_num_threads(1)
    cli.trainer.fit(cli.model, dm)
    dm.setup("test")
    t, q = held_out_windows(dm)
    repeats = 2 if quick else REPEATS
    rows = [
        ["exact pendulum", *timed(dm.system, t, q, repeats)],
        ["HNN, pendulum_positions.yaml", *timed(cli.model.eval(), t, q, repeats)],
    ]
    caption = (
        f"1 thread; {repeats} timed calls after a warm-up. The HNN's field runs as a float64 "
        "copy (the coarse search's ranking in float32); LM: Levenberg–Marquardt iterations "
        "of the slowest row; rms: the rollout's position residual on the 15 samples (the "
        "noise is 0.1)."
    )
    header = "field | starts | median s | fastest s | LM iterations | mean rms | usable"
    return caption + "\n\n" + table(header, rows)


if __name__ == "__main__":
    main({"observer": sys.modules[__name__]}, None)
