"""The 800-chunk chain-pendulum fits: a training step of each bundled config, 1 thread,
the matrix products' share of it, and the fit it adds up to (steps × step)."""

from __future__ import annotations

import sys

import torch
from common import main, measure, ms, quiet_cli, table

TITLE = "Chain pendulum, 800 chunks: the fit's cost"
#: the bundled configs, with what they train
CONFIGS = (
    ("chain2.yaml", "HNN, 3 × 256"),
    ("chain2_mechanical_hnn.yaml", "MechanicalHNN, two nets of 3 × 256"),
    ("chain2_mechanical_hnn_fast.yaml", "MechanicalHNN, two nets of 3 × 128"),
)
#: matrix products, as torch's profiler names them
GEMMS = ("aten::mm", "aten::addmm", "aten::bmm")


def stepper(config: str):
    """One Adam step of ``config``'s model on its training batches (the fit's loss and
    optimiser, without Lightning's loop), and the config's ``max_steps``."""
    cli = quiet_cli(config, seed=0)
    dm, model = cli.datamodule, cli.model
    dm.prepare_data()
    dm.setup("fit")
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    batches = [b for _, b in zip(range(4), dm.train_dataloader(), strict=False)]
    state = {"i": 0}

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        model.training_loss(batches[state["i"] % len(batches)])["loss"].backward()
        opt.step()
        state["i"] += 1

    return step, cli.trainer.max_steps


def gemm_share(step, n: int) -> float:
    """Seconds per step in matrix products (:data:`GEMMS`), by torch's profiler."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(n):
            step()
    us = sum(e.self_cpu_time_total for e in prof.key_averages() if e.key in GEMMS)
    return us * 1e-6 / n


def run(quick: bool) -> str:
    torch.set_num_threads(1)
    n, run_time = (3, 0.3) if quick else (20, 6.0)
    rows = []
    for config, what in CONFIGS:
        step, steps = stepper(config)
        for _ in range(3):
            step()
        s = measure(step, run_time)[0]
        g = gemm_share(step, n)
        rows.append([f"`{config}`", what, steps, ms(s), ms(g), f"{steps * s:.0f}"])
    return (
        "One training step of each 800-chunk config at its own batch (200 five-sample "
        "chunks, RK4, float32), 1 thread: the model's loss, `backward` and AdamW, without "
        f"Lightning's loop; median of `blocked_autorange` ({run_time} s). Matrix products: "
        f"torch profiler's self time of `mm`, `addmm` and `bmm` over {n} steps. A fit adds "
        "validation and Lightning's loop to steps × step.\n\n"
        + table(
            "config | model | steps | step (ms) | of which matrix products (ms) | steps × step (s)",
            rows,
        )
    )


if __name__ == "__main__":
    main({"chain_fit": sys.modules[__name__]}, None)
