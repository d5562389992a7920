"""``python -m hnn_pl reproduce``: the paper's Table 1, trained and evaluated here.

Every selected task × model × seed is trained from its bundled config (the same
YAML ``fit`` uses, so the settings are the paper's), then evaluated with both
protocols of :mod:`hnn_pl.evaluation`. Runs go to a pool of worker processes with
one torch thread each (on 2 cores two single-threaded runs beat one two-threaded
run); each finished run is written to the JSON file at once, so a failed or
interrupted run loses nothing else, and ``RESULTS.md`` is rewritten from it.
Each seed (``seed_everything``) draws its own initialisation and, as in the
reference code, its own data set, so spreads over seeds include data variance.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import signal
import statistics
import sys
import tempfile
import threading
import time
import traceback
import uuid
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from hnn_pl import tasks
from hnn_pl.commands.cli_errors import OneLineParser, non_negative_int, positive_int
from hnn_pl.safe_io import write_atomic

#: what the report says of a task beside its numbers (``"results"``) and how its
#: protocols read (``"reference"``, ``"clean"``; else the protocol's fields)
NOTES: dict[str, dict[str, str]] = {
    "real_pendulum": {
        "results": (
            "dissipative: the dissipative HNN (`real_pendulum_dissipative.yaml`, no published"
            " number). On the paper's forward differences it learns the decay those "
            "differences add (energy slope ≈ −0.045 per s against the recording's −0.011, as "
            "the baseline does); on central differences it follows the recording (−0.011) and"
            " its energy MSE falls below the HNN's: docs/friction.md."
        ),
    },
    "pixel": {
        "reference": (
            "the reference's evaluation (analyze-pixels, 2019-05-20): one trajectory from θ₀ "
            "= 0.2934, θ̇₀ = 0.7326, its first frame pair encoded, the latent integrated over"
            " [0, 0.98·200] frames at 200 points, decoded, re-encoded and read by a linear "
            "probe fitted on the training set through the HNN's encoder (for the baseline "
            "too: `reproduce` pairs each baseline with the HNN of its seed; time to accuracy "
            "uses each model's own), H = 1.9(1 − cos q) + p²"
        ),
        "clean": (
            "all held-out 200-frame trajectories, each model its own encoder and probe, H = "
            "1.875(1 − cos q) + p²"
        ),
    },
}


def _job_args(
    task: str, model: str, seed: int, max_steps: int | None, recipe: str = "paper"
) -> list[str]:
    config = tasks.get(task).config(model, recipe)
    from hnn_pl.commands.cli import quiet_args

    args = ["--config", config, f"--seed_everything={seed}", *quiet_args()]
    if max_steps is not None:
        args.append(f"--trainer.max_steps={max_steps}")
    return args


def run_one(
    task: str,
    model: str,
    seed: int,
    max_steps: int | None = None,
    recipe: str = "paper",
    overrides: tuple[str, ...] = (),
    model_path: str | None = None,
    tta: bool = True,
) -> dict:
    """Train one model from its config (plus CLI ``overrides`` such as
    ``"--data.init_args.differences=central"``) and evaluate it; never raises.
    ``model_path``: also ``torch.save`` the trained model's ``state_dict`` there.
    ``tta=False``: no time-to-accuracy checks (the record says ``tta_measured: False``).

    Returns:
        the run's record: identifiers, losses, both protocols' results, wall times
        (``train_s``, ``eval_s``), or ``error`` with the traceback.
    """
    record = {"task": task, "model": model, "seed": seed}
    with _quiet_lightning_runs():
        return _run_one(record, max_steps, recipe, overrides, model_path, tta)


def _run_one(
    record: dict,
    max_steps: int | None,
    recipe: str,
    overrides: tuple,
    model_path: str | None,
    measure_tta: bool,
) -> dict:
    task, model, seed = record["task"], record["model"], record["seed"]
    try:
        import torch

        torch.set_num_threads(1)
        from hnn_pl.commands.cli import cli_main
        from hnn_pl.commands.tta import TimeToAccuracy
        from hnn_pl.evaluation import evaluate_task

        args = _job_args(task, model, seed, max_steps, recipe) + list(overrides)
        cli = cli_main(args, run=False, save_config=False)
        torch.set_num_threads(1)
        cli.datamodule.prepare_data()
        cli.datamodule.setup("fit")
        tta = None
        if measure_tta:
            tta = TimeToAccuracy(task, every_n_steps=tasks.get(task).tta_every[recipe])
            cli.trainer.callbacks.append(tta)
        t0 = time.perf_counter()
        cli.trainer.fit(cli.model, cli.datamodule)
        t1 = time.perf_counter()
        record.update(evaluate_task(task, cli.model, cli.datamodule))
        record.update(
            train_s=t1 - t0 - (tta.scoring_seconds if tta else 0.0),
            eval_s=time.perf_counter() - t1,
            steps=cli.trainer.global_step,
            tta_measured=measure_tta,
        )
        if tta:
            record.update(
                tta=tta.reached, tta_state_target=tta.state_target, tta_history=tta.history
            )
        if model_path is not None:
            torch.save(cli.model.state_dict(), model_path)
    except Exception:  # noqa: BLE001 - one failed run must not lose the others
        record["error"] = traceback.format_exc()
    return record


@contextmanager
def _quiet_lightning_runs() -> Iterator[None]:
    """Lightning's per-run lines ("Seed set to", "GPU available", "`Trainer.fit`
    stopped") off inside: the progress lines are reproduce's own. Warnings stay."""
    import logging

    import lightning.pytorch  # noqa: F401 - it sets its loggers' level on import

    loggers = [logging.getLogger(name) for name in ("lightning.pytorch", "lightning.fabric")]
    levels = [log.level for log in loggers]
    for log in loggers:
        log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        for log, level in zip(loggers, levels):
            log.setLevel(level)


def _started(job: tuple[str, str, int], k: int, n: int, **kwargs) -> dict:
    """:func:`run_one` after printing ``[start k/n] task model seed s``."""
    print(f"[start {k}/{n}] {job[0]} {job[1]} seed {job[2]}", flush=True)
    return run_one(*job, **kwargs)


def _remaining(jobs: list, done: list, elapsed: float) -> str:
    """``, ~T s left``: the elapsed time scaled by the remaining runs' share of the
    tasks' relative costs (:attr:`hnn_pl.tasks.Task.cost`)."""
    cost = {j: tasks.get(j[0]).cost for j in jobs}
    spent = sum(cost[j] for j in done)
    if not spent:
        return ""
    left = elapsed * (sum(cost.values()) - spent) / spent
    return f", ~{left:.0f} s left" if left > 0 else ""


def _trained(task: str, model: str, seed: int, recipe: str, path: Path) -> Any:
    """The model and data module of a finished run, the model's weights from ``path``."""
    import torch

    from hnn_pl.commands.cli import cli_main

    cli = cli_main(_job_args(task, model, seed, None, recipe), run=False, save_config=False)
    cli.model.load_state_dict(torch.load(path, weights_only=True))
    return cli.model, cli.datamodule


def _through_hnn(task: str) -> bool:
    """Whether ``task``'s reference protocol reads every model through the HNN's encoder."""
    return tasks.get(task).reference.fields.get("probe_encoder") == "hnn"


def probe_through_hnn(records: list[dict], paths: dict[tuple, Path], recipe: str) -> None:
    """In place: for every run whose task's reference protocol reads frames through
    the HNN's encoder (pixel: ``probe_encoder="hnn"``, as the reference evaluated its
    baseline) and whose seed's HNN has weights in ``paths``, the
    reference protocol again with that HNN as ``probe_model``; the own-encoder result is
    kept as ``reference_own_encoder`` and ``reference_probe`` says which was used."""
    import torch

    from hnn_pl.evaluation import evaluate_task

    torch.set_num_threads(1)
    ok = {(r["task"], r["model"], r["seed"]): r for r in records if "error" not in r}
    for (task, model, seed), record in ok.items():
        if not _through_hnn(task) or record.get("reference_probe"):
            continue
        record["reference_probe"] = "own"
        hnn_key = (task, "hnn", seed)
        if model == "hnn" or hnn_key not in ok:
            continue
        if (task, model, seed) not in paths or hnn_key not in paths:
            continue
        net, dm = _trained(task, model, seed, recipe, paths[task, model, seed])
        hnn, _ = _trained(task, "hnn", seed, recipe, paths[hnn_key])
        dm.prepare_data()
        dm.setup("test")
        record["reference_own_encoder"] = record["reference"]
        again = evaluate_task(task, net, dm, hnn, protocols=("reference",), losses=False)
        record["reference"] = again["reference"]
        record["reference_probe"] = "hnn"


def _prepare_data(jobs: list[tuple[str, str, int]], recipe: str) -> dict[str, float]:
    """Generate every job's data once, before the workers start; seconds per task."""
    from hnn_pl.commands.cli import cli_main

    times: dict[str, float] = {}
    for task, model, seed in jobs:
        cli = cli_main(_job_args(task, model, seed, None, recipe), run=False)
        t0 = time.perf_counter()
        cli.datamodule.prepare_data()
        times[task] = times.get(task, 0.0) + time.perf_counter() - t0
    return times


def _median_worst(values: list[float]) -> tuple[float, float]:
    """Median and largest of the finite values (all our numbers are errors or times)."""
    values = [v for v in values if v is not None and math.isfinite(v)]
    return (statistics.median(values), max(values)) if values else (math.nan, math.nan)


def _abs(x: float | None) -> float | None:
    return None if x is None else abs(x)


def _is(record: dict, row: dict) -> bool:
    """Whether ``record`` is a finished run of ``row``'s task and model."""
    same = record["task"] == row["task"] and record["model"] == row["model"]
    return same and "error" not in record


def _fmt(median: float, worst: float | None = None) -> str:
    if math.isnan(median):
        return "—"
    return f"{median:.3e}" if worst is None or math.isnan(worst) else f"{median:.2e} ({worst:.2e})"


def _timed(runs: list[dict]) -> list[dict]:
    """The runs that measured time to accuracy (not ``reproduce --no-tta``)."""
    return [r for r in runs if r.get("tta_measured", True)]


def _tta(runs: list[dict]) -> str:
    """``median (worst) s, k/n reached``: time to the joint criterion of
    :class:`~hnn_pl.commands.tta.TimeToAccuracy` (published HNN energy MSE and, where the
    task has one, the paper recipe's clean state MSE) over the runs that measured it."""
    runs = _timed(runs)
    if not runs:
        return "not measured"
    secs = [r["tta"]["seconds"] if r.get("tta") else math.inf for r in runs]
    reached = sum(math.isfinite(s) for s in secs)
    if not reached:
        return f"not reached (0/{len(runs)})"
    med, worst = statistics.median(secs), max(secs)
    return f"{med:.1f} ({worst:.1f}) s, {reached}/{len(runs)}"


def summarize(records: list[dict]) -> list[dict]:
    """One row per (task, model): median and worst over seeds of every number."""
    rows = []
    for task in tasks.TASKS:
        for model in tasks.get(task).models:
            runs = [r for r in records if r["task"] == task and r["model"] == model]
            if not runs:
                continue
            ok = [r for r in runs if "error" not in r]
            row = {"task": task, "model": model, "seeds": len(ok), "failed": len(runs) - len(ok)}
            for key, get in {
                "train_loss": lambda r: r["train_loss"],
                "test_loss": lambda r: r["test_loss"],
                "ref_energy": lambda r: r["reference"]["energy_mse"],
                "clean_energy": lambda r: r["clean"]["energy_mse"],
                "indep_energy": lambda r: r.get("independent", {}).get("energy_mse"),
                "clean_state": lambda r: r["clean"].get("state_mse"),
                "clean_field": lambda r: r["clean"].get("field_error"),
                "clean_drift": lambda r: r["clean"].get("conserved_drift"),
                "clean_slope": lambda r: _abs(r["clean"].get("energy_drift_slope")),
                "floor_integrator": lambda r: r["clean"].get("floor_integrator_energy_mse"),
                "floor_chaos": lambda r: r["clean"].get("floor_chaos_energy_mse"),
                "train_s": lambda r: r["train_s"],
                "eval_s": lambda r: r["eval_s"],
            }.items():
                row[key] = _median_worst([get(r) for r in ok if get(r) is not None])
            row["tta"] = _tta(ok)
            rows.append(row)
    return rows


def _contributing(calls: list[dict], records: list[dict]) -> list[dict]:
    """The earlier calls that still own a kept run (runs are tagged with their call's
    ``id``); calls or runs written before tagging existed are all kept."""
    owners = {r.get("call") for r in records}
    return [c for c in calls if "id" not in c or None in owners or c["id"] in owners]


def write_markdown(records: list[dict], path: Path, meta: dict) -> None:
    """``RESULTS.md``: per task and model, ours (median and worst over seeds) beside the
    paper's."""
    from hnn_pl.evaluation import describe, task_protocol

    rows = summarize(records)
    lines = [
        "# Results: Table 1 reproduced",
        "",
        f"Written by `python -m hnn_pl reproduce` on {meta['date']} ({meta['machine']}); "
        f"{meta['command']}. Total wall time {meta['total_s']:.0f} s "
        f"({meta['workers']} worker processes, 1 torch thread each; data generation "
        f"{sum(meta['data_s'].values()):.1f} s), recipe `{meta.get('recipe', 'paper')}`. "
        "Ours: median (worst) over seeds, each seed drawing its own data; published: "
        "the reference README (± there is over trials, not seeds). Time to accuracy: "
        "training seconds until a check (periodic, its own cost excluded) finds both the "
        "energy MSE on the paper's protocol at or below the published HNN value and the "
        "state MSE on the clean protocol at or below the paper recipe's HNN median "
        "(`hnn_pl.tasks`, `paper_motion`; runs made before a task had one: energy "
        "only, see the motion table's last column), median (worst) over the seeds, and "
        "how many seeds reached it.",
        *(
            f"Merged with the runs of an earlier call: {c['command']} on {c['date']}, "
            f"{c['total_s']:.0f} s."
            for c in meta.get("earlier_calls", [])
        ),
        "",
        "| task | model | seeds | train loss (ours / paper) | test loss (ours / paper) "
        "| energy MSE, reference protocol (ours / paper) | energy MSE, clean protocol "
        "| HNN-conserved drift (clean) | train s | eval s | time to accuracy |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        pub = tasks.get(row["task"]).published.get(row["model"])
        paper = ["—"] * 3 if pub is None else [_fmt(pub[0]), _fmt(pub[1]), _fmt(pub[2], pub[3])]
        fail = f" ({row['failed']} failed)" if row["failed"] else ""
        lines.append(
            f"| {row['task']} | {row['model']} | {row['seeds']}{fail} "
            f"| {_fmt(*row['train_loss'])} / {paper[0]} "
            f"| {_fmt(*row['test_loss'])} / {paper[1]} "
            f"| {_fmt(*row['ref_energy'])} / {paper[2]} "
            f"| {_fmt(*row['clean_energy'])} | {_fmt(*row['clean_drift'])} "
            f"| {row['train_s'][0]:.1f} | {row['eval_s'][0]:.1f} | {row['tta']} |"
        )
    notes = {row["task"]: NOTES.get(row["task"], {}).get("results") for row in rows}
    lines += [f"\n**{task}.** {note}" for task, note in notes.items() if note]
    lines += ["", "## Long horizons (clean protocol)", ""]
    lines += [
        "Valid prediction time: the first time the normalised state error "
        "‖y_pred − y_true‖ / rms ‖y_true‖ passes 0.025 (the whole horizon if never), mean "
        "over trajectories; energy drift: least-squares slope in time of the predicted "
        "energy's relative change, absolute. Error split: the model's energy MSE beside "
        "the integrator floor (the true system through the same method and step) and "
        "the chaos floor (the true system from starts perturbed by 1e-4). Median (worst) "
        "over seeds.",
        "",
        "| task | model | valid prediction time | energy drift per unit time "
        "| energy MSE (model) | integrator floor | chaos floor |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        vpts = [r["clean"].get("valid_time") for r in records if _is(r, row)]
        vpts = [v for v in vpts if v is not None and math.isfinite(v)]
        if not vpts:
            continue
        vpt_med, vpt_worst = statistics.median(vpts), min(vpts)
        slope = row["clean_slope"]
        lines.append(
            f"| {row['task']} | {row['model']} | {vpt_med:.3g} ({vpt_worst:.3g}) "
            f"| {_fmt(*slope)} | {_fmt(*row['clean_energy'])} "
            f"| {_fmt(*row['floor_integrator'])} | {_fmt(*row['floor_chaos'])} |"
        )
    lines += ["", "## Motion (clean protocol)", ""]
    lines += [
        "State MSE: `mean_{t,b,d} (y_pred − y_true)²` over the held-out rollouts; field "
        "error: `sqrt(Σ ‖f_θ(y) − f(y)‖²) / sqrt(Σ ‖f(y)‖²)` summed over every true state "
        "`y` of the held-out trajectories (`hnn_pl.evaluation.metrics.field_error`; the real "
        "pendulum's `f` is the recording's central differences; pixel models: not "
        "applicable, their latent field has no true counterpart); valid prediction time "
        "as above (median, and the smallest over seeds). Median (worst) over the seeds "
        "that report each number (runs older than the field error have none). "
        "Target: the paper recipe's HNN medians (state MSE / field error) from "
        "`hnn_pl.tasks`; the state MSE target is the state half of time to accuracy.",
        "",
        "| task | model | state MSE | field error | valid prediction time "
        "| energy MSE (clean) | target: paper recipe HNN state MSE / field error "
        "| time-to-accuracy state target of these runs |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        runs = [r for r in records if _is(r, row)]
        vpts = [r["clean"].get("valid_time") for r in runs]
        vpts = [v for v in vpts if v is not None and math.isfinite(v)]
        vpt = f"{statistics.median(vpts):.3g} ({min(vpts):.3g})" if vpts else "—"
        field = _fmt(*row["clean_field"]) if tasks.get(row["task"]).has_true_field else "n/a"
        paper = tasks.get(row["task"]).paper_motion
        target = "—" if paper is None else f"{paper.state_mse:.3g} / {_fmt(paper.field_error)}"
        used = sorted({r.get("tta_state_target", math.inf) for r in _timed(runs)})
        used = ", ".join("none" if not math.isfinite(u) else f"{u:.3g}" for u in used) or "—"
        lines.append(
            f"| {row['task']} | {row['model']} | {_fmt(*row['clean_state'])} | {field} "
            f"| {vpt} | {_fmt(*row['clean_energy'])} | {target} | {used} |"
        )
    lines += ["", "## Baseline / HNN energy-MSE ratio", ""]
    lines += [
        "| task | reference protocol (ours) | paper | clean protocol (ours) |",
        "|---|---|---|---|",
    ]
    by = {(r["task"], r["model"]): r for r in rows}
    for task in tasks.TASKS:
        if (task, "baseline") in by and (task, "hnn") in by:
            b, h = by[task, "baseline"], by[task, "hnn"]
            published = tasks.get(task).published
            pub = published["baseline"].energy_mse / published["hnn"].energy_mse
            ref = b["ref_energy"][0] / h["ref_energy"][0]
            clean = b["clean_energy"][0] / h["clean_energy"][0]
            lines.append(f"| {task} | {ref:.3g} | {pub:.3g} | {clean:.3g} |")
    lines += ["", "## Energy MSE per seed (reference protocol / clean protocol)", ""]
    seeds = sorted({r["seed"] for r in records})
    lines += ["| task | model | " + " | ".join(f"seed {s}" for s in seeds) + " |"]
    lines += ["|---|---|" + "---|" * len(seeds)]
    ok = {(r["task"], r["model"], r["seed"]): r for r in records if "error" not in r}
    for row in rows:
        runs = [ok.get((row["task"], row["model"], seed)) for seed in seeds]
        cells = [
            f"{r['reference']['energy_mse']:.2e} / {r['clean']['energy_mse']:.2e}" if r else "—"
            for r in runs
        ]
        lines.append(f"| {row['task']} | {row['model']} | " + " | ".join(cells) + " |")
    lines += ["", "## Protocols", ""]
    lines += [
        "Reference: the published procedure with its quirks (`hnn_pl.tasks`); "
        "scipy RK45, one `solve_ivp` call per model on the flattened batch of starts. "
        "Clean: held-out starts, the task's energy, float64 per-trajectory `dopri5` at "
        "rtol = atol = 1e-9, ground truth at 1e-10 (`hnn_pl.tasks`).",
        "",
        "| task | reference | clean |",
        "|---|---|---|",
    ]
    for name in dict.fromkeys(r["task"] for r in records):
        ref, clean = (
            NOTES.get(name, {}).get(k) or describe(task_protocol(name, k))
            for k in ("reference", "clean")
        )
        lines.append(f"| {name} | {ref} | {clean} |")
    failures = [r for r in records if "error" in r]
    if failures:
        lines += ["", "## Failed runs", ""]
        for r in failures:
            last = r["error"].strip().splitlines()[-1]
            lines.append(f"- {r['task']} {r['model']} seed {r['seed']}: `{last}`")
    indep = [row for row in rows if not math.isnan(row["indep_energy"][0])]
    if indep:
        lines += ["", "## True-energy evaluation (independent)", ""]
        lines += [
            "The published procedure without its quirks (15 starts with each coordinate in "
            "±[0.2, 1], scipy RK45 at rtol = atol = 1e-12 on a float64 copy, t ∈ [0, 20], no "
            "time stretch, the system's true energy), as `benchmarks/independent.py`.",
            "",
            "| task | model | energy MSE, true energy |",
            "|---|---|---|",
        ]
        lines += [f"| {r['task']} | {r['model']} | {_fmt(*r['indep_energy'])} |" for r in indep]
    write_atomic(path, ("\n".join(lines) + "\n").encode())


def _new_run_dir(recipe: str) -> Path:
    """``results/<recipe>-<YYYYmmdd-HHMMSS>[-k]``, a folder that does not exist yet."""
    base = Path("results") / f"{recipe}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, k = base, 1
    while path.exists():
        path, k = base.with_name(f"{base.name}-{k}"), k + 1
    return path


def main(argv: list[str] | None = None) -> int:
    from hnn_pl.commands.cli_errors import program_name

    parser = OneLineParser(prog=f"{program_name()} reproduce", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=None,
        choices=list(tasks.TASKS),
        help="default: the state tasks (recipe traj: those with traj configs); add pixel "
        "explicitly",
    )
    parser.add_argument(
        "--models",
        nargs="+",
        default=["baseline", "hnn"],
        choices=list(tasks.MODELS),
        help="default: baseline hnn; dissipative runs where a task has it (real_pendulum)",
    )
    parser.add_argument(
        "--recipe",
        default="paper",
        choices=tasks.RECIPES,
        help="paper: the paper's settings (TASK.yaml); fast: the fast recipes (TASK_fast.yaml); "
        "traj: learning from the observed states only, trajectory objective (TASK_traj.yaml)",
    )
    parser.add_argument("--seeds", type=positive_int, default=3, help="number of seeds (0, 1, …)")
    parser.add_argument(
        "--first-seed",
        type=non_negative_int,
        default=0,
        help="start at this seed (extend a --merge run)",
    )
    parser.add_argument(
        "--workers", type=non_negative_int, default=2, help="processes; 0 runs in this process"
    )
    parser.add_argument(
        "--max-steps", type=positive_int, default=None, help="override every config's steps"
    )
    parser.add_argument(
        "--out",
        default=None,
        help="the Markdown table (default: a new results/<recipe>-<time>/RESULTS.md; "
        "an existing file is overwritten only when named here)",
    )
    parser.add_argument("--json", default=None, help="the raw records (default: OUT with .json)")
    parser.add_argument(
        "--models-dir",
        default=None,
        help="keep the pixel runs' weights there (default: a temporary folder, removed at "
        "the end); a pixel baseline is read through its seed's HNN found there, also one "
        "an earlier --merge call left",
    )
    parser.add_argument(
        "--no-tta",
        action="store_true",
        help="skip the time-to-accuracy checks (they cost more than the training in the "
        "paper recipes; the table then says 'not measured')",
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="keep the runs already in the JSON file that this call does not redo",
    )
    args = parser.parse_args(argv)
    if args.tasks is None:
        args.tasks = tasks.TRAJ_TASKS if args.recipe == "traj" else tasks.DEFAULT_TASKS
    out = Path(args.out) if args.out else _new_run_dir(args.recipe) / "RESULTS.md"
    json_path = Path(args.json) if args.json else out.with_suffix(".json")
    for option, path in (("--out", out), ("--json", json_path)):
        if path.is_dir():
            parser.error(f"{option} {path} is a directory; name the file to write")
        if path.parent.exists() and not path.parent.is_dir():
            parser.error(f"{option} {path}: {path.parent} is not a directory")
    jobs = [
        (t, m, s)
        for t in args.tasks
        for m in args.models
        if m in tasks.get(t).models_for(args.recipe)
        for s in range(args.first_seed, args.first_seed + args.seeds)
    ]
    if not jobs:
        parser.error(f"no task of {args.tasks} has a model of {args.models}")
    jobs.sort(key=lambda j: (-tasks.get(j[0]).cost, j[2], j[1]))  # longest first
    start = time.perf_counter()
    with _quiet_lightning_runs():
        data_s = _prepare_data(jobs, args.recipe)
    records: list[dict] = []
    if args.merge and json_path.exists():
        redo = set(jobs)
        old = json.loads(json_path.read_text())
        records = [r for r in old["runs"] if (r["task"], r["model"], r["seed"]) not in redo]
        earlier = old["meta"].pop("earlier_calls", []) + [old["meta"]]
        earlier = _contributing(earlier, records)
    kept = len(records)
    import torch

    meta = {
        "id": uuid.uuid4().hex,
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"{torch.backends.cpu.get_cpu_capability()} kernels, Python {platform.python_version()}",
        "command": f"`{parser.prog} " + " ".join(argv or sys.argv[2:]) + "`",
        "workers": max(args.workers, 1),
        "recipe": args.recipe,
        "data_s": data_s,
    }
    if kept:
        meta["earlier_calls"] = earlier

    finished: list[tuple[str, str, int]] = []

    def done(record: dict) -> None:
        finished.append((record["task"], record["model"], record["seed"]))
        record["call"] = meta["id"]
        records.append(record)
        meta["total_s"] = time.perf_counter() - start
        out.parent.mkdir(parents=True, exist_ok=True)
        json_path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(json_path, json.dumps({"meta": meta, "runs": records}, indent=1).encode())
        write_markdown(records, out, meta)
        status = (
            f"train {record['train_s']:.1f} s, eval {record['eval_s']:.1f} s, test loss "
            f"{record['test_loss']:.3e}, energy MSE ref {record['reference']['energy_mse']:.3e} "
            f"clean {record['clean']['energy_mse']:.3e}, state MSE "
            f"{record['clean'].get('state_mse', math.nan):.3e}, field error "
            f"{record['clean'].get('field_error', math.nan):.3e}"
            if "error" not in record
            else "FAILED: " + record["error"].strip().splitlines()[-1]
        )
        left = _remaining(jobs, finished, time.perf_counter() - run_start)
        print(
            f"[done {len(records) - kept}/{len(jobs)}, {meta['total_s']:.0f} s{left}] "
            f"{record['task']} {record['model']} seed {record['seed']}: {status}",
            flush=True,
        )

    run_start = time.perf_counter()
    keep = args.models_dir is not None
    model_dir = Path(args.models_dir) if keep else Path(tempfile.mkdtemp(prefix="hnn_pl_models_"))
    model_dir.mkdir(parents=True, exist_ok=True)

    def weights(task: str, model: str, seed: int) -> Path:
        return model_dir / f"{task}_{model}_{seed}_{args.recipe}.pt"

    paths = {job: weights(*job) for job in jobs if _through_hnn(job[0])}
    try:
        print(
            f"{len(jobs)} runs on {meta['workers']} worker(s); "
            f"data ready in {sum(data_s.values()):.1f} s",
            flush=True,
        )
        _run_jobs(jobs, args, done, paths)
        if paths:
            hnns = {(t, "hnn", s): weights(t, "hnn", s) for t, _, s in paths}
            found = {j: p for j, p in {**paths, **hnns}.items() if p.exists()}
            probe_through_hnn(records, found, args.recipe)
            write_atomic(json_path, json.dumps({"meta": meta, "runs": records}, indent=1).encode())
            write_markdown(records, out, meta)
    except (KeyboardInterrupt, BrokenProcessPool) as err:
        what = (
            "interrupted"
            if isinstance(err, KeyboardInterrupt)
            else ("a worker process died (killed, or out of memory)")
        )
        finished = len(records) - kept
        where = f"kept in {json_path} and {out}" if finished else "nothing written"
        print(
            f"{parser.prog}: {what}: {finished} of {len(jobs)} runs finished, {where}",
            file=sys.stderr,
            flush=True,
        )
        return 130 if isinstance(err, KeyboardInterrupt) else 2
    finally:
        if not keep:
            shutil.rmtree(model_dir, ignore_errors=True)
    print(f"wrote {out} and {json_path} in {time.perf_counter() - start:.0f} s")
    return 1 if any("error" in r for r in records) else 0


def _run_jobs(
    jobs: list[tuple[str, str, int]], args: Any, done: Any, paths: dict[tuple, Path]
) -> None:
    """Run every job (in this process for ``--workers 0``), ``done(record)`` as each
    finishes. Workers ignore Ctrl-C and die with this process (:func:`_die_with_parent`);
    a Ctrl-C while the pool starts is raised once it has started (:func:`_ctrl_c_held`);
    on Ctrl-C or a dead worker the others are killed and the pool is shut down before
    the error goes on (:func:`_stop`)."""
    kwargs = {"max_steps": args.max_steps, "recipe": args.recipe, "tta": not args.no_tta}
    if args.workers == 0:
        for k, job in enumerate(jobs, 1):
            done(_started(job, k, len(jobs), **kwargs, model_path=paths.get(job)))
        return
    pool = None
    try:
        with _ctrl_c_held():
            pool = ProcessPoolExecutor(
                args.workers,
                mp_context=get_context("spawn"),
                initializer=_die_with_parent,
                initargs=(os.getpid(),),
            )
            futures = [
                pool.submit(_started, job, k, len(jobs), **kwargs, model_path=paths.get(job))
                for k, job in enumerate(jobs, 1)
            ]
        for future in as_completed(futures):
            done(future.result())
    except BaseException:
        if pool is not None:
            _stop(pool)
        raise
    pool.shutdown()


def _stop(pool: ProcessPoolExecutor) -> None:
    """Kill ``pool``'s workers and wait for its manager thread to wind down.

    Not waiting (``shutdown(wait=False)``) leaves that thread closing its wake-up pipe
    while the interpreter's exit hook (``concurrent.futures.process._python_exit``,
    not under the pool's lock in Python 3.11) writes to it: ``OSError: [Errno 9] Bad
    file descriptor`` at exit, under load. With the workers dead the thread ends at
    once (it marks the pool broken and joins them)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.kill()
    pool.shutdown(wait=True, cancel_futures=True)


@contextmanager
def _ctrl_c_held() -> Iterator[None]:
    """Ctrl-C (SIGINT) while the worker pool starts, raised as ``KeyboardInterrupt``
    once it has started.

    A ``KeyboardInterrupt`` inside multiprocessing's launch of a worker leaves a worker
    the pool does not know (``reproduce`` then hangs at exit) or its pipes half made,
    and a worker that gets the terminal's Ctrl-C before its initializer ignores it
    prints a traceback. Meanwhile a SIGINT is recorded, and this thread blocks it: a
    worker spawned now starts with it blocked, until :func:`_die_with_parent` ignores
    and unblocks it (multiprocessing starts its resource tracker so; that start
    unblocks SIGINT in the thread, so the tracker is started first). Signal handlers
    live in the main thread: elsewhere, and without ``pthread_sigmask``, nothing is
    held."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "pthread_sigmask"
    ):
        yield
        return
    from multiprocessing import resource_tracker

    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # runs a pending one
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def _die_with_parent(parent: int) -> None:
    """In a worker: ignore Ctrl-C (the parent stops the pool) and die with the parent,
    by ``PR_SET_PDEATHSIG`` on Linux and a thread watching ``os.getppid()`` anywhere,
    so a killed ``reproduce`` leaves no worker (nor, with its pipes closed, the
    multiprocessing resource tracker) behind."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # see _ctrl_c_held
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL))
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="die-with-parent").start()


if __name__ == "__main__":
    sys.exit(main())
