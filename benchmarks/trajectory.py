"""Learning from observed states: the trajectory objective beside the derivative recipe.

Accuracy (issue 19): per task, seeds 0-9, each seed its own draw of the paper's noisy
states (σ = 0.1); on the same draw three HNNs: the derivative fast recipe handed the
exact derivatives (``TASK_fast.yaml``), the same recipe on central differences of the
noisy states (:func:`hnn_pl.data.differences.central_differences`: what a user with a
recording would otherwise do), and the trajectory recipe on the states only
(``TASK_traj.yaml``, run by ``reproduce --recipe traj``, which writes
``RESULTS_traj.md``); the spring also with half of each trajectory's samples dropped
(``keep_fraction: 0.5``). All scored as ``reproduce`` scores: the independent
true-energy evaluation (:mod:`independent`) and the clean protocol.

Time to accuracy: the energy MSE on the paper's protocol every few steps
(:class:`hnn_pl.experiments.tta.TimeToAccuracy` history, its scoring excluded) against
training seconds, median over seeds, all objectives on the same axes
(``docs/traj_tta.png``).

Cost: one trajectory step against what its field evaluations predict (step time ÷
(field calls per step × one field call, forward and backward, on the same rows)),
and Lightning's overhead (``fit`` against a bare loop of the same steps).
Recording: the measured pendulum (one recording, ten initialisations), the baseline, the
HNN and the dissipative HNN learning from the paper's forward differences, from central differences
and from the recorded states alone; clean-protocol energy MSE and the rollout's energy
slope against the held-out segment's own (−1.07 % per second).

``HNN_PL_TRAJ_TASKS=spring`` limits the accuracy part to the spring;
``HNN_PL_TRAJ_PARTS=recording,cost`` runs only those parts; ``HNN_PL_TRAJ_JOBS=2`` runs
the accuracy and recording parts' seeds two at a time (1 thread each; the cost part
always runs alone).
"""

from __future__ import annotations

import contextlib
import json
import os
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

import torch
from common import main, measure, ms, quiet_cli, table

from hnn_pl.commands import reproduce
from hnn_pl.commands.cli import quiet_run
from hnn_pl.data.differences import central_differences
from hnn_pl.evaluation import evaluate_task
from hnn_pl.experiments.collect import run_one
from hnn_pl.experiments.paper import PAPER
from hnn_pl.experiments.tta import TimeToAccuracy

TITLE = "Learning from observed states (trajectory objective)"
ROOT = Path(__file__).resolve().parents[1]
FIGURE = ROOT / "docs" / "traj_tta.png"
#: the tasks measured (``HNN_PL_TRAJ_TASKS`` overrides: the machine's budget)
TASKS = tuple(os.environ.get("HNN_PL_TRAJ_TASKS", "spring,pendulum").split(","))
#: the parts run (``HNN_PL_TRAJ_PARTS``, comma-separated)
PARTS = tuple(os.environ.get("HNN_PL_TRAJ_PARTS", "accuracy,recording,cost").split(","))
#: processes for the accuracy and recording parts (``HNN_PL_TRAJ_JOBS``)
JOBS = int(os.environ.get("HNN_PL_TRAJ_JOBS", "1"))
#: field evaluations per step of each window method (implicit midpoint: its typical
#: fixed-point iterations are data-dependent, so it is not in the cost table)
EVALS = {"euler": 1, "rk4": 4, "leapfrog": 2}
#: one run as ``reproduce`` makes it (picklable, for the process pool)
RUN_ONE = partial(run_one, build=quiet_run)


def fit(task: str, seed: int, quick: bool, central: bool) -> dict:
    """The derivative fast recipe's HNN on ``task`` (``central``: its derivative targets
    replaced by central differences of the same noisy states), scored as ``reproduce``
    scores the trajectory runs; with its time-to-accuracy history."""
    cli = quiet_cli(PAPER[task].config("hnn", "fast"), seed, 1, 20 if quick else None)
    dm = cli.datamodule
    dm.prepare_data()
    dm.setup("fit")
    if central:
        assert torch.equal(dm.obs_y_train, dm.x_train)  # the same noisy states
        dm.dx_train = central_differences(dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train)
    tta = TimeToAccuracy(task, every_n_steps=PAPER[task].tta_every["fast"])
    cli.trainer.callbacks.append(tta)
    t0 = time.perf_counter()
    cli.trainer.fit(cli.model, dm)
    train_s = time.perf_counter() - t0 - tta.scoring_seconds
    record = evaluate_task(task, cli.model, dm)
    return {**record, "train_s": train_s, "tta_history": tta.history}


@contextlib.contextmanager
def _pmap():
    """``map``, over ``JOBS`` processes when ``JOBS > 1``."""
    if JOBS == 1:
        yield map
    else:
        with ProcessPoolExecutor(JOBS) as pool:
            yield pool.map


def _raise_failed(runs: list[dict]) -> list[dict]:
    bad = [r["error"] for r in runs if "error" in r]
    if bad:
        raise RuntimeError(bad[0])
    return runs


def _mw(values: list[float]) -> str:
    return f"{statistics.median(values):.2e} ({max(values):.2e})"


def accuracy(quick: bool) -> tuple[str, dict]:
    """Every variant on every seed; the trajectory recipe through ``reproduce``
    (``RESULTS_traj.md``)."""
    n = 1 if quick else 10
    task_list = ("spring",) if quick else TASKS
    records = _traj_runs(task_list, ["hnn"], n, quick)
    runs = {}
    with _pmap() as pmap:
        for task in task_list:
            seeds = range(n)
            exact = pmap(fit, [task] * n, seeds, [quick] * n, [False] * n)
            central = pmap(fit, [task] * n, seeds, [quick] * n, [True] * n)
            runs[task, "exact derivatives (fast recipe)"] = list(exact)
            runs[task, "central differences (fast recipe)"] = list(central)
            runs[task, "states only (traj recipe)"] = [
                r for r in records if r["task"] == task and r["model"] == "hnn"
            ]
            if task == "spring" and not quick:
                half = [("--data.init_args.keep_fraction=0.5",)] * n
                args = ([task] * n, ["hnn"] * n, seeds, [None] * n, ["traj"] * n, half)
                runs[task, "half the samples (traj recipe)"] = _raise_failed(
                    list(pmap(RUN_ONE, *args))
                )
    rows = []
    for (task, name), rs in runs.items():
        scored = "independent" if all("independent" in r for r in rs) else "reference"
        ind = [r[scored]["energy_mse"] for r in rs]
        clean = [r["clean"]["energy_mse"] for r in rs]
        train = statistics.median(r["train_s"] for r in rs)
        per_seed = ", ".join(f"{x:.1e}" for x in ind)
        name += "" if scored == "independent" else " — paper's protocol"
        rows.append([task, name, len(rs), _mw(ind), _mw(clean), f"{train:.1f}", per_seed])
        print(rows[-1], flush=True)
    head = (
        "task | HNN trained on | seeds | true-energy MSE (independent), median (worst) "
        "| clean-protocol energy MSE | train s (median) | true-energy MSE per seed"
    )
    return table(head, rows), runs


#: the measured pendulum's models (name in ``reproduce``: label)
RECORDING_MODELS = {"baseline": "baseline", "hnn": "HNN", "dissipative": "dissipative HNN"}
#: what they learn from besides the recorded states: (label, recipe, overrides); the
#: trajectory recipe's runs come from ``reproduce`` (``RESULTS_traj.md``)
DIFFERENCES = (
    ("forward differences (the paper's targets; fast recipe)", "fast", ()),
    ("central differences (fast recipe)", "fast", ("--data.init_args.differences=central",)),
)


def _traj_runs(task_list, models: list[str], n: int, quick: bool) -> list[dict]:
    """The trajectory recipe's runs through ``reproduce`` (merged into ``RESULTS_traj.md``,
    a temporary one when ``quick``)."""
    out = (Path(tempfile.mkdtemp()) if quick else ROOT) / "RESULTS_traj.md"
    argv = ["--recipe", "traj", "--tasks", *task_list, "--models", *models, "--seeds", str(n)]
    argv += ["--workers", "0" if JOBS == 1 else str(JOBS), "--out", str(out), "--merge"]
    reproduce.main(argv + (["--max-steps", "20"] if quick else []))
    runs = json.loads(out.with_suffix(".json").read_text())["runs"]
    return _raise_failed([r for r in runs if r["task"] in task_list and r["seed"] < n])


def recording(quick: bool) -> str:
    """The measured pendulum from its recording alone beside its differences: each model's
    clean-protocol energy MSE and the rollout's energy slope against the held-out
    segment's own. ``quick``: the dissipative HNN alone (every code path, a third of the
    fits)."""
    n = 1 if quick else 10
    models = {"dissipative": RECORDING_MODELS["dissipative"]} if quick else RECORDING_MODELS
    traj = _traj_runs(["real_pendulum"], list(models), n, quick)
    steps = [20 if quick else None] * n
    rows = []
    with _pmap() as pmap:
        for model, label in models.items():
            for name, recipe, over in DIFFERENCES:
                args = (["real_pendulum"] * n, [model] * n, range(n), steps, [recipe] * n)
                rs = _raise_failed(list(pmap(RUN_ONE, *args, [over] * n)))
                rows.append(_recording_row(label, name, rs))
            states = [r for r in traj if r["model"] == model]
            rows.append(_recording_row(label, "the recording's states only (traj recipe)", states))
    head = (
        "model | learns from | seeds | energy MSE, clean, median (worst) "
        "| energy MSE, paper's protocol | energy slope per s, median (range) "
        "| the recording's slope | state MSE, clean | train s (median)"
    )
    return table(head, rows)


def _recording_row(label: str, name: str, rs: list[dict]) -> list:
    clean = [r["clean"] for r in rs]
    slopes = [c["energy_drift_slope"] for c in clean]
    row = [
        label,
        name,
        len(rs),
        _mw([c["energy_mse"] for c in clean]),
        _mw([r["reference"]["energy_mse"] for r in rs]),
        f"{statistics.median(slopes):+.4f} ({min(slopes):+.4f} … {max(slopes):+.4f})",
        f"{clean[0]['true_energy_drift_slope']:+.4f}",
        _mw([c["state_mse"] for c in clean]),
        f"{statistics.median(r['train_s'] for r in rs):.1f}",
    ]
    print(row, flush=True)
    return row


def figure(runs: dict, quick: bool) -> str:
    """Median energy MSE (paper's protocol) against training seconds, both recipes."""
    from hnn_pl.plotting import pyplot

    plt = pyplot()

    task_list = sorted({task for task, _ in runs})
    fig, axes = plt.subplots(1, len(task_list), figsize=(4.5 * len(task_list), 3.4), squeeze=False)
    axes = axes[0]
    for ax, task in zip(axes, task_list, strict=True):
        for (t, name), rs in runs.items():
            if t != task or "half" in name:
                continue
            n = min(len(r["tta_history"]) for r in rs)
            if n == 0:
                continue
            secs = [statistics.median(r["tta_history"][i][1] for r in rs) for i in range(n)]
            err = [statistics.median(r["tta_history"][i][2] for r in rs) for i in range(n)]
            ax.loglog(secs, err, marker=".", label=name)
        ax.axhline(PAPER[task].published["hnn"].energy_mse, color="k", lw=0.8, ls="--")
        ax.set(
            title=task, xlabel="training seconds (1 thread)", ylabel="energy MSE, paper's protocol"
        )
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    out = Path(tempfile.mkdtemp()) / FIGURE.name if quick else FIGURE
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
    settings = [("rk4", 1), ("rk4", 2), ("leapfrog", 2)]
    for method, substeps in settings[:1] if quick else settings:
        rows.append(cost_row(method, substeps, quick))
        print(rows[-1], flush=True)
    head = (
        "window method | windows per step | field calls per step "
        "| one field call, fwd+bwd (ms) | trajectory step (ms) | step ÷ (calls × call) "
        "| bare loop s | Lightning fit s | Lightning overhead"
    )
    return table(head, rows)


def run(quick: bool = False) -> str:
    parts = []
    if "accuracy" in PARTS:
        acc, runs = accuracy(quick)
        fig = figure(runs, quick)
        parts += [acc, f"Time to accuracy, both objectives on the same axes: `docs/{fig}`."]
    if "recording" in PARTS:
        parts.append(recording(quick))
    if "cost" in PARTS:
        parts.append(cost(quick))
    return "\n\n".join(parts)


if __name__ == "__main__":
    main({"trajectory": sys.modules[__name__]}, None)
