"""``hnn-pl reproduce --recipe positions``: learning from positions alone, measured.

For each task with positions configs and each seed, on the paper's draws (the same data
for every row), these runs are trained and scored under ONE protocol, the task's clean
protocol with starts inferred from the first :data:`POSITION_SAMPLES` observed
positions of each held-out trajectory (:func:`~hnn_pl.evaluation.observer.observe`):

- ``positions``: ``TASK_positions.yaml`` — the momenta withheld, learned as latent
  states (``hnn``, ``baseline``, ``dissipative`` where the task has it);
- ``positions, half the samples``: the same with half of each trajectory's samples
  dropped at random (``keep_fraction: 0.5``, irregular times) and windows of half as
  many samples, so of about the same duration (:data:`HALF`);
- ``states``: ``TASK_traj.yaml`` — the states-only recipe, momenta observed;
- the spring's structured twin, ``TASK_positions_mechanical_hnn.yaml``, on positions and
  with half the samples, and the same model on the states recipe (like for like);
- ``finite differences``: ``TASK_positions_fd.yaml`` — a derivative fit on finite
  differences of the same positions.

Scores (gauge-invariant): position MSE against the clean truth, the true energy's MSE
from ``(q, q̇)`` with ``q̇`` the model's own, valid prediction time on positions, the
energy drift slopes; and the floor: the true field through the same observer.
Written to ``RESULTS_positions.md`` and ``.json``: per-seed values, medians and worst.
"""

from __future__ import annotations

import json
import statistics
import time
import traceback
from typing import Any

from hnn_pl.experiments.collect import Build, machine, quiet_lightning_runs

#: half of each trajectory's samples dropped at random (irregular times), in windows of half
#: the positions configs' 10 samples, so that a window keeps about its duration (the
#: spring's structured twin, 10 seeds: position MSE median 0.0260 with windows of 5, 0.0379
#: with 10)
HALF = ("--data.init_args.keep_fraction=0.5", "--data.init_args.window=5")


#: the simulated tasks with positions configs (the real pendulum's rows differ)
SIMULATED = ("spring", "pendulum")

#: the options that put the mass-matrix-structured HNN on a config of another model (the
#: states recipe's like-for-like row of a structured positions twin)
MECHANICAL = (
    "--model.class_path=hnn_pl.models.MechanicalHNN",
    "--model.init_args.shared_trunk=false",
)

#: the simulated tasks with a structured positions twin (``TASK_positions_mechanical_hnn.yaml``)
STRUCTURED = ("spring",)


def _simulated_rows(t: str) -> list[tuple[str, str, str, tuple[str, ...]]]:
    """The rows of a simulated task; with a structured twin (:data:`STRUCTURED`), its
    positions rows and the same model on the states recipe (like for like)."""
    rows = [
        ("positions", "hnn", f"{t}_positions.yaml", ()),
        ("positions", "baseline", f"{t}_positions_baseline.yaml", ()),
        ("positions, half the samples", "hnn", f"{t}_positions.yaml", HALF),
        ("states", "hnn", f"{t}_traj.yaml", ()),
        ("finite differences", "hnn", f"{t}_positions_fd.yaml", ()),
    ]
    if t in STRUCTURED:
        twin = f"{t}_positions_mechanical_hnn.yaml"
        rows[2:2] = [
            ("positions", "mechanical_hnn", twin, ()),
            ("positions, half the samples", "mechanical_hnn", twin, HALF),
        ]
        rows.insert(5, ("states", "mechanical_hnn", f"{t}_traj.yaml", MECHANICAL))
    return rows


#: the rows: task → (label, model, config, extra CLI options)
ROWS: dict[str, list[tuple[str, str, str, tuple[str, ...]]]] = {
    t: _simulated_rows(t) for t in SIMULATED
}
ROWS["real_pendulum"] = [
    ("positions", "hnn", "real_pendulum_positions.yaml", ()),
    ("positions", "dissipative", "real_pendulum_positions_dissipative.yaml", ()),
    ("positions", "baseline", "real_pendulum_positions_baseline.yaml", ()),
    ("states", "hnn", "real_pendulum_traj.yaml", ()),
    ("states", "dissipative", "real_pendulum_traj_dissipative.yaml", ()),
]

#: the scores reported, in table order
SCORES = ("position_mse", "energy_mse", "position_valid_time", "floor_observer_position_mse")
SCORES += ("energy_drift_slope", "true_energy_drift_slope")


def run_row(
    task: str, row: tuple, seed: int, max_steps: int | None = None, *, build: Build
) -> dict[str, Any]:
    """Train one row's model for ``seed`` (built by ``build``) and score it under the
    observer protocol; never raises (``error`` holds the traceback). Times: ``train_s``
    the fit, ``observer_s`` the starts' inference for the held-out trajectories."""
    label, model, config, extra = row
    record: dict[str, Any] = {"task": task, "row": label, "model": model, "seed": seed}
    try:
        import torch

        from hnn_pl.evaluation import evaluate, task_protocol
        from hnn_pl.evaluation.observer import POSITION_SAMPLES
        from hnn_pl.evaluation.views import observed_starts

        options = [f"--seed_everything={seed}", *extra]
        options += [f"--trainer.max_steps={max_steps}"] if max_steps else []
        cli = build(config, options)
        torch.set_num_threads(1)
        cli.datamodule.prepare_data()
        cli.datamodule.setup("fit")
        t0 = time.perf_counter()
        cli.trainer.fit(cli.model, cli.datamodule)
        record["train_s"] = time.perf_counter() - t0
        protocol = task_protocol(task, "clean", {"observer_samples": POSITION_SAMPLES})
        cli.datamodule.setup("test")
        t0 = time.perf_counter()
        observed_starts(cli.model.eval(), cli.datamodule, POSITION_SAMPLES, protocol)
        record["observer_s"] = time.perf_counter() - t0
        metrics, _ = evaluate(cli.model, cli.datamodule, protocol)
        record.update({k: metrics.get(k) for k in SCORES})
    except Exception:  # noqa: BLE001 - one failed run must not lose the others
        record["error"] = traceback.format_exc()
    return record


def collect(
    tasks: list[str], seeds: list[int], workers: int, max_steps: int | None, build: Build
) -> list:
    """Every row of ``tasks`` for every seed, ``workers`` processes (0: in this one)."""
    jobs = [(t, row, s, max_steps, build) for t in tasks for row in ROWS[t] for s in seeds]
    if workers == 0:
        return [_announce(k, len(jobs), *job) for k, job in enumerate(jobs, 1)]
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(_announce, k, len(jobs), *job) for k, job in enumerate(jobs, 1)]
        return [f.result() for f in futures]


def _announce(
    k: int, n: int, task: str, row: tuple, seed: int, max_steps: int | None, build: Build
) -> dict:
    print(f"[start {k}/{n}] {task} {row[0]} {row[1]} seed {seed}", flush=True)
    with quiet_lightning_runs():
        return run_row(task, row, seed, max_steps, build=build)


def summarise(records: list[dict]) -> list[dict]:
    """One entry per (task, row, model): median and worst of each score over the seeds
    (worst: the largest error, the shortest valid time; slopes: median only)."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((r["task"], r["row"], r["model"]), []).append(r)
    out = []
    for (task, row, model), runs in groups.items():
        ok = [r for r in runs if "error" not in r]
        entry = {
            "task": task,
            "row": row,
            "model": model,
            "seeds": len(ok),
            "failed": len(runs) - len(ok),
        }
        for key in (*SCORES, "train_s", "observer_s"):
            values = [r[key] for r in ok if r.get(key) is not None]
            if values:
                worst = min(values) if key == "position_valid_time" else max(values)
                entry[key] = (statistics.median(values), worst)
        out.append(entry)
    return out


def _cell(entry: dict, key: str) -> str:
    if key not in entry:
        return "—"
    median, worst = entry[key]
    if "slope" in key or key.endswith("_s"):
        return f"{median:.3g}"
    return f"{median:.3g} ({worst:.3g})"


def render(summary: list[dict], records: list[dict], meta: dict) -> str:
    """The Markdown page: the medians table, the criteria, the per-seed values."""
    head = (
        "| task | data | model | seeds | position MSE | energy MSE from (q, q̇) | valid time "
        "(positions) | observer floor (true field) | energy slope / truth's | train s "
        "| observer s |"
    )
    lines = [
        "# Results: learning from positions alone",
        "",
        f"`{meta['command']}` ({meta['machine']}; {meta['wall_s']:.0f} s). "
        "Median (worst) over seeds, each seed its own draw; every row on the same draws and "
        f"scored the same way: starts inferred from the first {meta['samples']} observed positions "
        "of each held-out trajectory, then the clean protocol. Positions MSE against the clean "
        "truth; energy: the system's true energy from the positions and the model's own "
        "velocities; floor: the true field through the same observer.",
        "",
        head,
        "|---" * (head.count("|") - 1) + "|",
    ]
    for e in summary:
        slope = "—"
        if "energy_drift_slope" in e and "true_energy_drift_slope" in e:
            slope = f"{e['energy_drift_slope'][0]:.3g} / {e['true_energy_drift_slope'][0]:.3g}"
        cells = [e["task"], e["row"], e["model"], str(e["seeds"])]
        cells += [_cell(e, k) for k in ("position_mse", "energy_mse", "position_valid_time")]
        cells += [_cell(e, "floor_observer_position_mse"), slope]
        cells += [_cell(e, "train_s"), _cell(e, "observer_s")]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", *criteria(summary), "", "## Per seed (position MSE / energy MSE)", ""]
    lines += per_seed(records)
    return "\n".join(lines) + "\n"


def _get(summary: list[dict], task: str, row: str, model: str = "hnn") -> dict:
    return next((e for e in summary if (e["task"], e["row"], e["model"]) == (task, row, model)), {})


def _ratio(a: dict, b: dict, key: str) -> float:
    """The ratio of ``a``'s median of ``key`` to ``b``'s (``nan`` when either lacks it)."""
    return a[key][0] / b[key][0] if key in a and key in b else float("nan")


def criteria(summary: list[dict]) -> list[str]:
    """The targets as measured ratios of medians, one line each."""
    out = ["## Criteria (ratios of medians)", ""]
    for task in SIMULATED:
        pos, st = _get(summary, task, "positions"), _get(summary, task, "states")
        fd = _get(summary, task, "finite differences")
        half = _get(summary, task, "positions, half the samples")
        if not (pos and st):
            continue
        out.append(
            f"- {task}: positions / states: position MSE "
            f"{_ratio(pos, st, 'position_mse'):.2f} (target ≤ 2), energy "
            f"{_ratio(pos, st, 'energy_mse'):.2f} (≤ 3), training {_ratio(pos, st, 'train_s'):.2f} "
            f"(≤ 2); finite differences / positions: position MSE "
            f"{_ratio(fd, pos, 'position_mse'):.1f}, energy {_ratio(fd, pos, 'energy_mse'):.1f} "
            f"(≥ 3); half the samples / all: {_ratio(half, pos, 'position_mse'):.2f} (≤ 2)"
        )
        m = "mechanical_hnn"
        twin, twin_half = (
            _get(summary, task, "positions", m),
            _get(summary, task, "positions, half the samples", m),
        )
        if twin:
            same = _get(summary, task, "states", m)
            out.append(
                f"- {task}, the structured twin ({m}) from positions / the states recipe (hnn): "
                f"position MSE {_ratio(twin, st, 'position_mse'):.2f}, energy "
                f"{_ratio(twin, st, 'energy_mse'):.2f}, training "
                f"{_ratio(twin, st, 'train_s'):.2f}; "
                f"like for like ({m} from states): position MSE "
                f"{_ratio(twin, same, 'position_mse'):.2f}; half the samples / all: "
                f"{_ratio(twin_half, twin, 'position_mse'):.2f}"
            )
    d = _get(summary, "real_pendulum", "positions", "dissipative")
    ds = _get(summary, "real_pendulum", "states", "dissipative")
    if d and ds and "energy_drift_slope" in d:
        slope, truth = d["energy_drift_slope"][0], d["true_energy_drift_slope"][0]
        out.append(
            f"- real_pendulum, dissipative from the angle alone: energy slope {slope:.4g} per s, "
            f"{slope / truth:.2f} of the recording's {truth:.4g} (target 0.75–1.25); position "
            f"MSE {_ratio(d, ds, 'position_mse'):.2f} of the states-only dissipative's (≤ 1.5), "
            f"training {_ratio(d, ds, 'train_s'):.2f} (≤ 2)"
        )
    return out


def per_seed(records: list[dict]) -> list[str]:
    """``| task | data | model | seed 0 | seed 1 | … |`` of position MSE / energy MSE."""
    seeds = sorted({r["seed"] for r in records})
    lines = ["| task | data | model | " + " | ".join(f"seed {s}" for s in seeds) + " |"]
    lines.append("|---" * (3 + len(seeds)) + "|")
    rows: dict[tuple, dict[int, str]] = {}
    for r in records:
        cell = (
            "failed"
            if "error" in r
            else f"{r['position_mse']:.3g} / {(r['energy_mse'] or float('nan')):.3g}"
        )
        rows.setdefault((r["task"], r["row"], r["model"]), {})[r["seed"]] = cell
    for key, cells in rows.items():
        lines.append(
            "| " + " | ".join(key) + " | " + " | ".join(cells.get(s, "") for s in seeds) + " |"
        )
    return lines


def run(call: Any, build: Build) -> int:
    """The campaign of a ``reproduce`` call (:class:`hnn_pl.experiments.reproduce.Call`:
    its ``tasks``, ``seeds``, ``workers``, ``max_steps``, ``out``, ``command``), runs made
    by ``build``: writes the page and the JSON records."""
    from hnn_pl.evaluation.observer import POSITION_SAMPLES

    tasks = [t for t in (call.tasks or list(ROWS)) if t in ROWS]
    start = time.perf_counter()
    records = collect(tasks, list(call.seeds), call.workers, call.max_steps, build)
    meta = {"command": call.command, "machine": machine(), "wall_s": time.perf_counter() - start}
    meta["samples"] = POSITION_SAMPLES
    out = call.out
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = summarise(records)
    out.write_text(render(summary, records, meta))
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "runs": records}, indent=1))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
