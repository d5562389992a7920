"""Learning from observed states: the trajectory objective beside the derivative recipe.

Accuracy: spring and pendulum, seeds 0-9, each seed its own draw of the paper's noisy
states (σ = 0.1). On the same draw: the derivative fast recipe handed the exact
derivatives (``TASK_fast.yaml``), the same recipe on central differences of the noisy
states (what a user with a recording would otherwise do), and the trajectory recipe
(``TASK_traj.yaml``, the states only); the spring again with half of each
trajectory's samples dropped (``keep_fraction: 0.5``). Scored by the independent
true-energy evaluation (:mod:`independent`) and the clean protocol.

Time to accuracy: the energy MSE on the paper's protocol every few steps
(:class:`hnn_pl.callbacks.TimeToAccuracy` history, its scoring excluded) against
training seconds, median over the seeds, both recipes on the same axes
(``docs/traj_tta.png``).

Cost: one trajectory step against what its field evaluations predict (step time ÷
(field calls per step × one field call, forward and backward, on the same rows)),
and the Lightning overhead (``fit`` against a bare loop of the same steps).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import torch
from common import main, measure, ms, quiet_cli, table

from hnn_pl import tasks
from hnn_pl.callbacks import TimeToAccuracy
from hnn_pl.data.differences import central_differences
from hnn_pl.evaluate import evaluate_protocol, evaluate_reference

TITLE = "Learning from observed states (trajectory objective)"
FIGURE = Path(__file__).resolve().parents[1] / "docs" / "traj_tta.png"
#: field evaluations per step of each window method (implicit midpoint: its typical
#: fixed-point iterations are data-dependent, so it is not in the cost table)
EVALS = {"euler": 1, "rk4": 4, "leapfrog": 2}


def fit(task: str, recipe: str, seed: int, quick: bool, central=False, overrides=()) -> dict:
    """One HNN fit from the bundled config (``central``: the derivative targets replaced
    by central differences of the noisy states), scored; with its TTA history."""
    steps = 20 if quick else None
    cli = quiet_cli(tasks.get(task).config("hnn", recipe), seed, 1, steps, overrides)
    dm = cli.datamodule
    dm.prepare_data()
    dm.setup("fit")
    if central:
        dm.dx_train = central_differences(dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train)
        assert torch.equal(dm.obs_y_train, dm.x_train)  # the same noisy states
    tta = TimeToAccuracy(task, every_n_steps=tasks.get(task).tta_every[recipe])
    cli.trainer.callbacks.append(tta)
    t0 = time.perf_counter()
    cli.trainer.fit(cli.model, dm)
    train_s = time.perf_counter() - t0 - tta.scoring_seconds
    task_ = tasks.get(task)
    return {
        "independent": evaluate_reference(cli.model, dm, task, task_.independent)["energy_mse"],
        "clean": evaluate_protocol(cli.model, dm, task_.clean)["energy_mse"],
        "train_s": train_s,
        "history": tta.history,
    }


def _mw(values: list[float]) -> str:
    return f"{statistics.median(values):.2e} ({max(values):.2e})"


def accuracy(quick: bool) -> tuple[str, dict]:
    seeds = range(2 if quick else 10)
    variants = [
        ("derivative fast recipe, exact derivatives", "fast", False, ()),
        ("derivative fast recipe, central differences", "fast", True, ()),
        ("trajectory recipe, states only", "traj", False, ()),
    ]
    rows, runs = [], {}
    for task in ("spring",) if quick else ("spring", "pendulum"):
        extra = [
            (
                "trajectory recipe, half the samples",
                "traj",
                False,
                ("--data.init_args.keep_fraction=0.5",),
            )
        ]
        for name, recipe, central, over in variants + (extra if task == "spring" else []):
            rs = [fit(task, recipe, s, quick, central, over) for s in seeds]
            runs[task, name] = rs
            ind, cl = [r["independent"] for r in rs], [r["clean"] for r in rs]
            rows.append(
                [
                    task,
                    name,
                    _mw(ind),
                    _mw(cl),
                    f"{statistics.median(r['train_s'] for r in rs):.1f}",
                    ", ".join(f"{x:.1e}" for x in ind),
                ]
            )
            print(rows[-1], flush=True)
    head = (
        "task | HNN trained on | true-energy MSE, median (worst) | clean-protocol energy MSE "
        "| train s (median) | true-energy MSE per seed"
    )
    return table(head, rows), runs


def figure(runs: dict, quick: bool) -> str:
    """Median energy MSE (paper's protocol) against training seconds, both recipes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, task in zip(axes, ("spring", "pendulum"), strict=True):
        for (t, name), rs in runs.items():
            if t != task or "half" in name:
                continue
            n = min(len(r["history"]) for r in rs)
            if n == 0:
                continue
            secs = [statistics.median(r["history"][i][1] for r in rs) for i in range(n)]
            err = [statistics.median(r["history"][i][2] for r in rs) for i in range(n)]
            ax.loglog(secs, err, marker=".", label=name)
        ax.axhline(tasks.get(task).published["hnn"].energy_mse, color="k", lw=0.8, ls="--")
        ax.set(
            title=task, xlabel="training seconds (1 thread)", ylabel="energy MSE, paper's protocol"
        )
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    out = FIGURE.with_name("traj_tta_quick.png") if quick else FIGURE
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out.name


def cost_row(method: str, substeps: int, quick: bool) -> list:
    """One row of :func:`cost`: the spring trajectory recipe with ``method``."""
    over = (f"--model.init_args.traj_method={method}", f"--model.init_args.substeps={substeps}")
    n_steps = 20 if quick else 60
    cli = quiet_cli("spring_traj.yaml", 0, 1, n_steps, over)
    dm, model = cli.datamodule, cli.model
    dm.prepare_data()
    dm.setup("fit")
    y, t, index = next(iter(dm.train_dataloader()))
    model.init_states(dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train)
    model.train()
    opt = torch.optim.Adam(model.param_groups(), lr=1e-4)
    x = y[:, 0].clone()

    def field_call():
        model.field.vector_field(None, x).sum().backward()

    def step():
        opt.zero_grad()
        model.training_loss((y, t, index))["loss"].backward()
        opt.step()

    call_s, _ = measure(field_call)
    step_s, _ = measure(step)
    calls = (y.shape[1] - 1) * substeps * EVALS[method] + (method == "leapfrog")
    t0 = time.perf_counter()
    for _ in range(n_steps):
        step()
    bare = time.perf_counter() - t0
    cli = quiet_cli("spring_traj.yaml", 0, 1, n_steps, over)
    cli.datamodule.prepare_data()
    t0 = time.perf_counter()
    cli.trainer.fit(cli.model, cli.datamodule)
    lit = time.perf_counter() - t0
    return [
        f"{method}, substeps {substeps}",
        len(y),
        calls,
        ms(call_s),
        ms(step_s),
        f"{step_s / (calls * call_s):.2f}",
        f"{bare:.2f}",
        f"{lit:.2f}",
        f"{100 * (lit / bare - 1):.0f} %",
    ]


def cost(quick: bool) -> str:
    """Trajectory step ÷ its field evaluations, and Lightning's share, spring HNN."""
    rows = []
    for method, substeps in [("rk4", 1), ("rk4", 2), ("leapfrog", 2)]:
        rows.append(cost_row(method, substeps, quick))
        print(rows[-1], flush=True)
    head = (
        "window method | windows per step | field calls per step "
        "| one field call, fwd+bwd (ms) | trajectory step (ms) | step ÷ (calls × call) "
        "| bare loop s | Lightning fit s | Lightning overhead"
    )
    return table(head, rows)


def run(quick: bool = False) -> str:
    acc, runs = accuracy(quick)
    fig = figure(runs, quick)
    return (
        acc
        + f"\n\nTime to accuracy, both objectives on the same axes: `docs/{fig}`.\n\n"
        + cost(quick)
    )


if __name__ == "__main__":
    main({"trajectory": sys.modules[__name__]}, None)
