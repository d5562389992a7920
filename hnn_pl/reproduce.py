"""``python -m hnn_pl reproduce``: the paper's Table 1, trained and evaluated here.

Every selected task × model × seed is trained from its bundled config (the same
YAML ``fit`` uses, so the settings are the paper's), then evaluated with both
protocols of :mod:`hnn_pl.evaluate`. Runs go to a pool of worker processes with
one torch thread each (on 2 cores two single-threaded runs beat one two-threaded
run); each finished run is written to the JSON file at once, so a failed or
interrupted run loses nothing else, and ``RESULTS.md`` is rewritten from it.
Seeds change the model's initialisation (``seed_everything``); every seed sees the
same data set (data seed 0), as the paper had one data set per task.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
import traceback
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

#: task -> (baseline config, HNN config)
CONFIGS = {
    "spring": ("spring_baseline.yaml", "spring.yaml"),
    "pendulum": ("pendulum_baseline.yaml", "pendulum.yaml"),
    "real_pendulum": ("real_pendulum_baseline.yaml", "real_pendulum.yaml"),
    "two_body": ("two_body_baseline.yaml", "two_body.yaml"),
    "three_body": ("three_body_baseline.yaml", "three_body.yaml"),
    "pixel": ("pixel_baseline.yaml", "pixel.yaml"),
}
#: what runs without --tasks: the state tasks (the pixel task adds ~6 min per run)
DEFAULT_TASKS = ["spring", "pendulum", "real_pendulum", "two_body", "three_body"]
MODELS = ("baseline", "hnn")

#: the reference README's numbers (SPEC): (train loss, test loss, energy MSE, energy ±)
PUBLISHED = {
    ("spring", "baseline"): (3.7134e-02, 3.6656e-02, 1.7077e-01, 2.06e-02),
    ("spring", "hnn"): (3.6933e-02, 3.5928e-02, 3.8416e-04, 6.53e-05),
    ("pendulum", "baseline"): (3.2606e-02, 3.5273e-02, 4.1519e-02, 9.62e-03),
    ("pendulum", "hnn"): (3.2787e-02, 3.5586e-02, 2.4852e-02, 5.42e-03),
    ("real_pendulum", "baseline"): (2.7455e-03, 2.1864e-03, 3.8564e-01, 6.92e-02),
    ("real_pendulum", "hnn"): (9.2376e-03, 5.9584e-03, 1.4477e-02, 4.65e-03),
    ("two_body", "baseline"): (3.2682e-05, 2.9575e-05, 6.3276e-02, 3.36e-02),
    ("two_body", "hnn"): (2.9959e-06, 2.8218e-06, 3.8751e-05, 5.04e-06),
    ("three_body", "baseline"): (9.5573e-02, 3.8000e-01, 1.0906e02, 7.74e01),
    ("three_body", "hnn"): (8.0346e-02, 4.8809e-01, 4.1926e-02, 3.39e-02),
    ("pixel", "baseline"): (1.7731e-04, 1.7306e-04, 9.2748e-03, 1.14e-03),
    ("pixel", "hnn"): (1.8683e-04, 1.8451e-04, 1.5315e-04, 8.42e-06),
}


def _job_args(task: str, model: str, seed: int, max_steps: int | None) -> list[str]:
    config = CONFIGS[task][MODELS.index(model)]
    args = ["--config", config, f"--seed_everything={seed}", "--trainer.logger=false"]
    args += ["--trainer.enable_checkpointing=false", "--trainer.enable_progress_bar=false"]
    args += ["--trainer.callbacks=[]", "--trainer.limit_val_batches=0"]
    args += ["--trainer.enable_model_summary=false"]
    if max_steps is not None:
        args.append(f"--trainer.max_steps={max_steps}")
    return args


def run_one(task: str, model: str, seed: int, max_steps: int | None = None) -> dict:
    """Train one model from its config and evaluate it; never raises.

    Returns:
        the run's record: identifiers, losses, both protocols' results, wall times
        (``train_s``, ``eval_s``), or ``error`` with the traceback.
    """
    record = {"task": task, "model": model, "seed": seed}
    try:
        import torch

        torch.set_num_threads(1)
        from hnn_pl.cli import cli_main
        from hnn_pl.evaluate import evaluate, evaluate_pixel

        cli = cli_main(_job_args(task, model, seed, max_steps), run=False)
        cli.datamodule.prepare_data()
        cli.datamodule.setup("fit")
        t0 = time.perf_counter()
        cli.trainer.fit(cli.model, cli.datamodule)
        t1 = time.perf_counter()
        if task == "pixel":
            record.update(evaluate_pixel(cli.model, cli.datamodule))
        else:
            record.update(evaluate(cli.model.field, cli.datamodule, task))
        record.update(
            train_s=t1 - t0, eval_s=time.perf_counter() - t1, steps=cli.trainer.global_step
        )
    except Exception:  # noqa: BLE001 - one failed run must not lose the others
        record["error"] = traceback.format_exc()
    return record


def _prepare_data(tasks: list[str]) -> dict[str, float]:
    """Generate every task's data once, before the workers start; returns seconds."""
    from hnn_pl.cli import cli_main

    times = {}
    for task in tasks:
        cli = cli_main(_job_args(task, "hnn", 0, None), run=False)
        t0 = time.perf_counter()
        cli.datamodule.prepare_data()
        times[task] = time.perf_counter() - t0
    return times


def _mean_std(values: list[float]) -> tuple[float, float]:
    values = [v for v in values if v is not None and math.isfinite(v)]
    if not values:
        return math.nan, math.nan
    return statistics.fmean(values), statistics.stdev(values) if len(values) > 1 else 0.0


def _fmt(mean: float, std: float | None = None) -> str:
    if math.isnan(mean):
        return "—"
    return f"{mean:.3e}" if std is None or math.isnan(std) else f"{mean:.3e} ± {std:.1e}"


def summarize(records: list[dict]) -> list[dict]:
    """One row per (task, model): means ± std over seeds of every number."""
    rows = []
    for task in CONFIGS:
        for model in MODELS:
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
                "clean_state": lambda r: r["clean"].get("state_mse"),
                "clean_drift": lambda r: r["clean"].get("conserved_drift"),
                "train_s": lambda r: r["train_s"],
                "eval_s": lambda r: r["eval_s"],
            }.items():
                row[key] = _mean_std([get(r) for r in ok if get(r) is not None])
            rows.append(row)
    return rows


def _contributing(calls: list[dict], records: list[dict]) -> list[dict]:
    """The earlier calls that still own a kept run (runs are tagged with their call's
    ``id``); calls or runs written before tagging existed are all kept."""
    owners = {r.get("call") for r in records}
    return [c for c in calls if "id" not in c or None in owners or c["id"] in owners]


def write_markdown(records: list[dict], path: Path, meta: dict) -> None:
    """``RESULTS.md``: per task and model, ours (mean ± std over seeds) beside the paper's."""
    from hnn_pl.evaluate import CLEAN, PIXEL_PROTOCOLS, REFERENCE

    rows = summarize(records)
    lines = [
        "# Results: Table 1 reproduced",
        "",
        f"Written by `python -m hnn_pl reproduce` on {meta['date']} ({meta['machine']}); "
        f"{meta['command']}. Total wall time {meta['total_s']:.0f} s "
        f"({meta['workers']} worker processes, 1 torch thread each; data generation "
        f"{sum(meta['data_s'].values()):.1f} s). Ours: mean ± std over seeds; "
        "published: the reference README (± there is over trials, not seeds).",
        *(
            f"Merged with the runs of an earlier call: {c['command']} on {c['date']}, "
            f"{c['total_s']:.0f} s."
            for c in meta.get("earlier_calls", [])
        ),
        "",
        "| task | model | seeds | train loss (ours / paper) | test loss (ours / paper) "
        "| energy MSE, reference protocol (ours / paper) | energy MSE, clean protocol "
        "| HNN-conserved drift (clean) | train s | eval s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        pub = PUBLISHED.get((row["task"], row["model"]), (math.nan,) * 4)
        fail = f" ({row['failed']} failed)" if row["failed"] else ""
        lines.append(
            f"| {row['task']} | {row['model']} | {row['seeds']}{fail} "
            f"| {_fmt(*row['train_loss'])} / {_fmt(pub[0])} "
            f"| {_fmt(*row['test_loss'])} / {_fmt(pub[1])} "
            f"| {_fmt(*row['ref_energy'])} / {_fmt(pub[2], pub[3])} "
            f"| {_fmt(*row['clean_energy'])} | {_fmt(*row['clean_drift'])} "
            f"| {row['train_s'][0]:.1f} | {row['eval_s'][0]:.1f} |"
        )
    lines += ["", "## Baseline / HNN energy-MSE ratio", ""]
    lines += [
        "| task | reference protocol (ours) | paper | clean protocol (ours) |",
        "|---|---|---|---|",
    ]
    by = {(r["task"], r["model"]): r for r in rows}
    for task in CONFIGS:
        if (task, "baseline") in by and (task, "hnn") in by:
            b, h = by[task, "baseline"], by[task, "hnn"]
            pub = PUBLISHED[task, "baseline"][2] / PUBLISHED[task, "hnn"][2]
            ref = b["ref_energy"][0] / h["ref_energy"][0]
            clean = b["clean_energy"][0] / h["clean_energy"][0]
            lines.append(f"| {task} | {ref:.3g} | {pub:.3g} | {clean:.3g} |")
    lines += ["", "## Energy MSE per seed (reference protocol / clean protocol)", ""]
    seeds = sorted({r["seed"] for r in records})
    lines += ["| task | model | " + " | ".join(f"seed {s}" for s in seeds) + " |"]
    lines += ["|---|---|" + "---|" * len(seeds)]
    for row in rows:
        cells = []
        for seed in seeds:
            run = next(
                (
                    r
                    for r in records
                    if (r["task"], r["model"], r["seed"]) == (row["task"], row["model"], seed)
                ),
                None,
            )
            ok = run is not None and "error" not in run
            cells.append(
                f"{run['reference']['energy_mse']:.2e} / {run['clean']['energy_mse']:.2e}"
                if ok
                else "—"
            )
        lines.append(f"| {row['task']} | {row['model']} | " + " | ".join(cells) + " |")
    lines += ["", "## Protocols", ""]
    lines += [
        "Reference: the published procedure with its quirks (`hnn_pl.evaluate.REFERENCE`); "
        "scipy RK45, one `solve_ivp` call per model on the flattened batch of starts. "
        "Clean: held-out starts, the task's energy, float64 per-trajectory `dopri5` at "
        "rtol = atol = 1e-9, ground truth at 1e-10 (`hnn_pl.evaluate.CLEAN`).",
        "",
        "| task | reference | clean |",
        "|---|---|---|",
    ]
    for task in CONFIGS:
        if task == "pixel":
            ref, clean = PIXEL_PROTOCOLS["reference"], PIXEL_PROTOCOLS["clean"]
        else:
            ref, clean = _protocol_text(REFERENCE[task]), _protocol_text(CLEAN[task])
        lines.append(f"| {task} | {ref} | {clean} |")
    failures = [r for r in records if "error" in r]
    if failures:
        lines += ["", "## Failed runs", ""]
        for r in failures:
            last = r["error"].strip().splitlines()[-1]
            lines.append(f"- {r['task']} {r['model']} seed {r['seed']}: `{last}`")
    path.write_text("\n".join(lines) + "\n")


def _protocol_text(p) -> str:
    from dataclasses import asdict, fields

    default = type(p)()
    changed = {
        f.name: getattr(p, f.name)
        for f in fields(p)
        if getattr(p, f.name) != getattr(default, f.name)
    }
    base = ", ".join(f"{k}={v}" for k, v in asdict(default).items())
    return ", ".join(f"{k}={v}" for k, v in changed.items()) or f"defaults ({base})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m hnn_pl reproduce", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=DEFAULT_TASKS,
        choices=list(CONFIGS),
        help="default: the state tasks; add pixel explicitly",
    )
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    parser.add_argument("--seeds", type=int, default=3, help="number of seeds (0, 1, …)")
    parser.add_argument("--workers", type=int, default=2, help="processes; 0 runs in this process")
    parser.add_argument("--max-steps", type=int, default=None, help="override every config's steps")
    parser.add_argument("--out", default="RESULTS.md", help="the Markdown table")
    parser.add_argument("--json", default=None, help="the raw records (default: OUT with .json)")
    parser.add_argument(
        "--merge",
        action="store_true",
        help="keep the runs already in the JSON file that this call does not redo",
    )
    args = parser.parse_args(argv)
    out = Path(args.out)
    json_path = Path(args.json) if args.json else out.with_suffix(".json")
    jobs = [(t, m, s) for t in args.tasks for m in args.models for s in range(args.seeds)]
    # longest first, so the pool ends together
    order = ["three_body", "two_body", "pixel", "pendulum", "spring", "real_pendulum"]
    jobs.sort(key=lambda j: (order.index(j[0]) if j[0] in order else 99, j[2], j[1]))
    start = time.perf_counter()
    data_s = _prepare_data(list(dict.fromkeys(t for t, _, _ in jobs)))
    records: list[dict] = []
    if args.merge and json_path.exists():
        redo = set(jobs)
        old = json.loads(json_path.read_text())
        records = [r for r in old["runs"] if (r["task"], r["model"], r["seed"]) not in redo]
        earlier = old["meta"].pop("earlier_calls", []) + [old["meta"]]
        earlier = _contributing(earlier, records)
    kept = len(records)
    meta = {
        "id": uuid.uuid4().hex,
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}",
        "command": "`python -m hnn_pl reproduce " + " ".join(argv or sys.argv[2:]) + "`",
        "workers": max(args.workers, 1),
        "data_s": data_s,
    }
    if kept:
        meta["earlier_calls"] = earlier

    def done(record: dict) -> None:
        record["call"] = meta["id"]
        records.append(record)
        meta["total_s"] = time.perf_counter() - start
        json_path.write_text(json.dumps({"meta": meta, "runs": records}, indent=1))
        write_markdown(records, out, meta)
        status = (
            f"train {record['train_s']:.1f} s, eval {record['eval_s']:.1f} s, test loss "
            f"{record['test_loss']:.3e}, energy MSE ref {record['reference']['energy_mse']:.3e} "
            f"clean {record['clean']['energy_mse']:.3e}"
            if "error" not in record
            else "FAILED: " + record["error"].strip().splitlines()[-1]
        )
        print(
            f"[{len(records) - kept}/{len(jobs)} {meta['total_s']:.0f} s] {record['task']} "
            f"{record['model']} seed {record['seed']}: {status}",
            flush=True,
        )

    print(
        f"{len(jobs)} runs on {meta['workers']} worker(s); "
        f"data ready in {sum(data_s.values()):.1f} s",
        flush=True,
    )
    if args.workers == 0:
        for job in jobs:
            done(run_one(*job, max_steps=args.max_steps))
    else:
        with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(run_one, *job, max_steps=args.max_steps) for job in jobs]
            for future in as_completed(futures):
                done(future.result())
    print(f"wrote {out} and {json_path} in {time.perf_counter() - start:.0f} s")
    return 1 if any("error" in r for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
