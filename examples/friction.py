"""Friction on the measured pendulum: ``python examples/friction.py [--steps N] [--seeds S]
[--out DIR]``.

Trains the baseline, the HNN and the dissipative HNN (paper recipe, seeds 0 … S − 1,
default 3) on the measured pendulum's forward differences (the paper's data) and on
central differences, scores each with ``reproduce``'s evaluation, and writes
DIR/friction_table.md (median and worst over seeds; the friction page includes it) and
DIR/friction.png (energy along each model's rollout of the held-out segment beside the
measured energy, central differences, seed 0). DIR defaults to the repository's
``docs/``; N to the configs' 2000 steps.
"""

from __future__ import annotations

import argparse
import statistics
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


def table(seeds: range = SEEDS, steps: int | None = None) -> str:
    rows = []
    for diff in DIFFERENCES:
        for model in MODELS:
            override = (f"--data.init_args.differences={diff}",)
            runs = [
                run_one(
                    "real_pendulum", model, s, steps, overrides=override, tta=False, build=quiet_run
                )
                for s in seeds
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


def figure(path: Path, steps: int | None = None) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    measured = None
    for model in MODELS:
        config = "real_pendulum.yaml" if model == "hnn" else f"real_pendulum_{model}.yaml"
        args = [f"--config={config}", "--seed_everything=0", "--threads=1"]
        args += ["--data.init_args.differences=central", "--trainer.logger=false"]
        args += ["--trainer.enable_progress_bar=false", "--trainer.callbacks=[]"]
        args += ["--trainer.enable_checkpointing=false"]
        args += [] if steps is None else [f"--trainer.max_steps={steps}"]
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


def main(steps: int | None = None, seeds: int = len(SEEDS), out: Path = DOCS) -> Path:
    """The table (:func:`table`) and the figure (:func:`figure`) into ``out``; the table's
    path."""
    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows = table(range(seeds), steps)
    figure(out / "friction.png", steps)
    recipe = "Adam 1e-3, 2000 full-batch steps" if steps is None else f"{steps} steps"
    doc = f"""Written by `python examples/friction.py` in {time.perf_counter() - start:.0f} s
(1 torch thread). Each model's paper recipe (`real_pendulum.yaml`,
`real_pendulum_baseline.yaml`, `real_pendulum_dissipative.yaml`: {recipe}), seeds
0–{seeds - 1}; median (worst) over seeds. Forward: the paper's targets
`(y[i+1] − y[i])/Δt`; central: `(y[i+2] − y[i])/(2Δt)` at `y[i+1]`
(`--data.init_args.differences=central`). Energy `2.4(1 − cos θ) + θ̇²`; slope: the
least-squares slope of the rollout's relative energy change over the held-out segment
(t = 81 … 99 s), beside the measured segment's own.

{rows}
"""
    path = out / "friction_table.md"
    path.write_text(doc)
    return path


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=None, help="training steps of each model")
    parser.add_argument("--seeds", type=int, default=len(SEEDS), help="seeds 0 … S − 1")
    parser.add_argument("--out", type=Path, default=DOCS, help="where the table and figure go")
    args = parser.parse_args()
    table_path = main(args.steps, args.seeds, args.out)
    print(f"wrote {table_path} and {args.out / 'friction.png'}")
