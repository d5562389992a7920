"""Friction on the measured pendulum: ``python examples/friction.py [what else ran]``.

Trains the baseline, the HNN and the dissipative HNN (paper recipe, seeds 0-2) on the
measured pendulum's forward differences (the paper's data) and on central differences,
scores each with ``reproduce``'s evaluation, and writes docs/friction.md (median and
worst over seeds) and docs/friction.png (energy along each model's rollout of the
held-out segment beside the measured energy, central differences, seed 0).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import matplotlib
import torch

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from hnn_pl import rollout  # noqa: E402
from hnn_pl.commands.cli import cli_main, quiet_run  # noqa: E402
from hnn_pl.experiments.collect import run_one  # noqa: E402

DOCS = Path(__file__).resolve().parent.parent / "docs"
MODELS = {"baseline": "baseline", "hnn": "HNN", "dissipative": "dissipative HNN"}
DIFFERENCES = ("forward", "central")
SEEDS = range(3)


def _mw(values: list[float], fmt: str = "{:.2e}") -> str:
    worst = max(values, key=abs)
    return f"{fmt.format(statistics.median(values))} ({fmt.format(worst)})"


def table() -> str:
    rows = []
    for diff in DIFFERENCES:
        for model in MODELS:
            override = (f"--data.init_args.differences={diff}",)
            runs = [
                run_one("real_pendulum", model, s, overrides=override, build=quiet_run)
                for s in SEEDS
            ]
            bad = [r["error"] for r in runs if "error" in r]
            if bad:
                raise RuntimeError(bad[0])
            clean = [r["clean"] for r in runs]
            rows.append(
                f"| {diff} | {MODELS[model]} | {_mw([r['test_loss'] for r in runs])} "
                f"| {_mw([r['reference']['energy_mse'] for r in runs])} "
                f"| {_mw([c['energy_mse'] for c in clean])} "
                f"| {_mw([c['energy_drift_slope'] for c in clean], '{:+.4f}')} "
                f"| {clean[0]['true_energy_drift_slope']:+.4f} "
                f"| {statistics.median(r['train_s'] for r in runs):.1f} |"
            )
            print(rows[-1], flush=True)
    header = (
        "| differences | model | test loss | energy MSE, paper protocol | energy MSE, clean "
        "| energy slope per unit t (model) | measured slope | train s |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    return header + "\n" + "\n".join(rows)


def figure(path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    measured = None
    for model in MODELS:
        config = "real_pendulum.yaml" if model == "hnn" else f"real_pendulum_{model}.yaml"
        args = [f"--config={config}", "--seed_everything=0", "--threads=1"]
        args += ["--data.init_args.differences=central", "--trainer.logger=false"]
        args += ["--trainer.enable_progress_bar=false", "--trainer.callbacks=[]"]
        args += ["--trainer.enable_checkpointing=false"]
        cli = cli_main(args, run=False, save_config=False)
        cli.trainer.fit(cli.model, cli.datamodule)
        dm = cli.datamodule
        t, y_true = dm.rollout_target(None, None)
        energy = dm.system.energy
        traj = rollout(cli.model, y_true[0].double(), t.double(), energy=energy)
        if measured is None:
            measured = energy(y_true.double())[:, 0]
            ax.plot(t, measured, "k.", ms=3, label="measured")
        ax.plot(t, traj.e_pred[:, 0], label=MODELS[model])
    ax.set(xlabel="t (s)", ylabel="2.4(1 − cos θ) + θ̇²", title="held-out segment, from its start")
    ax.legend(frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    torch.set_num_threads(1)
    start = time.perf_counter()
    rows = table()
    figure(DOCS / "friction.png")
    when = time.strftime("%Y-%m-%d")
    beside = f", beside {sys.argv[1]}" if len(sys.argv) > 1 else ""
    doc = f"""# Friction on the measured pendulum

Written by `python examples/friction.py` on {when} in {time.perf_counter() - start:.0f} s
(1 torch thread{beside}). Each model's paper recipe (`real_pendulum.yaml`,
`real_pendulum_baseline.yaml`, `real_pendulum_dissipative.yaml`: Adam 1e-3, 2000 full-batch
steps), seeds 0-2; median (worst) over seeds. Forward: the paper's targets
`(y[i+1] − y[i])/Δt`; central: `(y[i+2] − y[i])/(2Δt)` at `y[i+1]`
(`--data.init_args.differences=central`). Energy `2.4(1 − cos θ) + θ̇²`; slope: the
least-squares slope of the rollout's relative energy change over the held-out segment
(t = 81 … 99 s), beside the measured segment's own.

{rows}

![energy along the held-out segment](friction.png)
"""
    (DOCS / "friction.md").write_text(doc)
    print(f"wrote {DOCS / 'friction.md'} and friction.png")


if __name__ == "__main__":
    main()
