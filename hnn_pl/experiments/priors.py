"""``hnn-pl reproduce --recipe priors``: every model's prior on one protocol per task.

Each model (:data:`MODELS`) is trained on each task and data size (:data:`DATA`) for each
seed, the same data for every model, and scored the same way:

- the state tasks ``spring`` and ``pendulum``: the fast recipe's config
  (``TASK_fast.yaml``), scored by the task's clean protocol: the energy MSE and the state
  MSE;
- the chain pendulums ``chain2`` and ``chain3`` (2 and 3 links, the constrained-HNN
  benchmark, ``docs/chain_pendulum.md``): the bundled configs of 100 chunks
  (``chainN_100*.yaml``) and of 800 (``chainN*.yaml``), scored by the benchmark's median
  relative rollout error
  (:meth:`~hnn_pl.data.chain_pendulum.ChainPendulumData.rollout_errors`) beside its chaos
  floor and, for 2 links, the published numbers (:data:`PUBLISHED`).

A model runs from its bundled config where one exists (``STEM_MODEL.yaml``, ``STEM.yaml``
for the HNN), else from ``STEM.yaml`` with its class swapped on the command line
(``--model.class_path=…``): the configs are read by name, so their recipes flow in. The
Lagrangian models (``lnn``, ``mechanical_lnn``) read the ``(q, p)`` data through the data's
system (:class:`~hnn_pl.models.velocity.VelocityChart`); a run whose model found none fails.

Written to ``RESULTS_priors.md`` and ``.json`` after every finished run: per-seed values,
medians and worst, training times; a failed run keeps its traceback and costs no other.
``python -m hnn_pl.experiments.results RESULTS_priors.json`` renders the page again.
Imports nothing heavy at import time (``reproduce --help`` parses with these names).
"""

from __future__ import annotations

import json
import math
import statistics
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

#: the models of the campaign → their classes
CLASSES = {
    "baseline": "hnn_pl.models.Baseline",
    "hnn": "hnn_pl.models.HNN",
    "lnn": "hnn_pl.models.LNN",
    "mechanical_hnn": "hnn_pl.models.MechanicalHNN",
    "mechanical_lnn": "hnn_pl.models.MechanicalLNN",
    "mechanical_hnn_fast": "hnn_pl.models.MechanicalHNN",
}
MODELS = tuple(CLASSES)
#: recipes of a model rather than models: a row only where the data has a config of its
#: own (``STEM_MODEL.yaml``), never the class swapped into another recipe
VARIANTS = ("mechanical_hnn_fast",)

#: the state tasks (scored by their clean protocol) and the chain tasks (by the
#: benchmark's rollout error)
STATE_TASKS = ("spring", "pendulum")
CHAIN_TASKS = ("chain2", "chain3")
TASKS = (*STATE_TASKS, *CHAIN_TASKS)

#: the training chunks of the chain pendulum's two data sizes (100 runs by default)
CHUNKS = (100, 800)
DEFAULT_CHUNKS = (100,)

#: task → data label → the stem of its configs
DATA: dict[str, dict[str, str]] = {
    "spring": {"fast recipe": "spring_fast"},
    "pendulum": {"fast recipe": "pendulum_fast"},
    "chain2": {"100 chunks": "chain2_100", "800 chunks": "chain2"},
    "chain3": {"100 chunks": "chain3_100", "800 chunks": "chain3"},
}

#: where the published numbers come from
SOURCE = (
    "Finzi, Wang and Wilson, Simplifying Hamiltonian and Lagrangian Neural Networks via "
    "Explicit Constraints (NeurIPS 2020), notebooks/data-efficiency-pendulum.csv of "
    "mfinzi/constrained-hamiltonian-neural-networks at c624a63 (docs/chain_pendulum.md): "
    "the 2-link pendulum, median over the 100 test trajectories of the per-trajectory "
    "geometric mean over time, trained on (θ, θ̇)"
)

#: chunks → published model → its median relative rollout error (:data:`SOURCE`)
PUBLISHED: dict[int, dict[str, float]] = {
    100: {
        "NeuralODE": 2.1e-1,
        "HNN": 2.3e-2,
        "DeLaN": 1.25e-2,
        "CHNN": 7.3e-4,
        "CLNN": 4.1e-4,
    },
    800: {
        "NeuralODE": 5.6e-2,
        "HNN": 8.3e-4,
        "DeLaN": 8.1e-4,
        "CHNN": 8.7e-5,
        "CLNN": 8.9e-5,
    },
}
#: the published 2-link chaos floor (:data:`SOURCE`; 5.72e-5 in a second run)
PUBLISHED_FLOOR = 5.70e-5
#: the chain task whose models have published numbers (:data:`PUBLISHED`) and targets
PUBLISHED_TASK = "chain2"
#: chain task → its published chaos floor (3 links: the reference's own run of its
#: chaos-floor code, docs/chain_pendulum.md)
PUBLISHED_FLOORS = {"chain2": PUBLISHED_FLOOR, "chain3": 9.51e-5}

#: our model → the published model of the same structure. The published "HNN" already
#: has the mass-matrix structure and "DeLaN" is its Lagrangian twin; neither has a plain
#: counterpart, so the plain HNN and LNN are set beside the structured ones they must match.
COUNTERPART = {
    "baseline": "NeuralODE",
    "hnn": "HNN",
    "lnn": "DeLaN",
    "mechanical_hnn": "HNN",
    "mechanical_lnn": "DeLaN",
    "mechanical_hnn_fast": "HNN",
}

#: the targets on the chain pendulum (2 links, medians over 5 seeds): (chunks, model,
#: bound on the median rollout error, why that bound)
TARGETS = (
    (800, "hnn", 8.3e-4, "the published HNN"),
    (800, "lnn", 8.1e-4, "the published DeLaN"),
    (800, "mechanical_lnn", 8.1e-4, "the published DeLaN, of the same structure"),
    (800, "mechanical_hnn", 1.7e-4, "within 2× of the published CHNN"),
    (100, "mechanical_hnn", 1.5e-3, "within about 2× of the published CHNN"),
    (800, "mechanical_hnn_fast", 8.3e-4, "the published HNN, from a fit of at most 10 min"),
)
#: the training-time targets (2 links, medians): (chunks, model, bound in seconds, what)
TIME_TARGETS = ((800, "mechanical_hnn_fast", 600.0, "one core"),)
#: the seeds a target's median is over
TARGET_SEEDS = 5
#: the chaos floor's target: within this fraction of :data:`PUBLISHED_FLOOR`
FLOOR_TOLERANCE = 0.3

#: the scores of each kind of task, in table order
STATE_SCORES = ("energy_mse", "state_mse")
CHAIN_SCORES = ("rollout_error", "chaos_floor")


class Row(NamedTuple):
    """One row of the table: ``task``, ``data`` (a label of :data:`DATA`), ``model``."""

    task: str
    data: str
    model: str


def rows(
    tasks: list[str] | None = None,
    models: list[str] | None = None,
    chunks: tuple[int, ...] = DEFAULT_CHUNKS,
) -> list[Row]:
    """The rows of ``tasks × data × models`` (``None``: all of them), the chain
    pendulum's data sizes those of ``chunks``; the costliest data first."""
    labels = {f"{n} chunks" for n in chunks}
    found = [
        Row(task, data, model)
        for task in tasks or TASKS
        for data in DATA[task]
        if task not in CHAIN_TASKS or data in labels
        for model in models or MODELS
        if model not in VARIANTS or bundled(f"{DATA[task][data]}_{model}.yaml")
    ]
    return sorted(found, key=lambda r: -_cost(r))


def _cost(row: Row) -> float:
    """Relative cost for the pool's order: the chain's 800 chunks, then 100, then the rest."""
    if row.task in CHAIN_TASKS:
        return float(row.data.split()[0])
    return 1.0


def config_of(row: Row) -> tuple[str, tuple[str, ...]]:
    """The bundled config of ``row`` and the options that swap its model's class:
    ``STEM_MODEL.yaml`` (``STEM.yaml`` for the HNN) if it is bundled, else ``STEM.yaml``
    with ``--model.class_path``."""
    stem = DATA[row.task][row.data]
    own = f"{stem}.yaml" if row.model == "hnn" else f"{stem}_{row.model}.yaml"
    if bundled(own):
        return own, ()
    return f"{stem}.yaml", (f"--model.class_path={CLASSES[row.model]}",)


def bundled(name: str) -> bool:
    """Whether ``name`` is a bundled config (the package ``hnn_pl.configs``, the
    repository's ``configs/`` in a source tree), where the commands look names up."""
    from importlib.resources import files

    try:
        return files("hnn_pl.configs").joinpath(name).is_file()
    except ModuleNotFoundError:  # a source tree put on sys.path by hand, not installed
        return (Path(__file__).resolve().parents[2] / "configs" / name).is_file()


def run_row(row: Row, seed: int, max_steps: int | None, build: Any) -> dict[str, Any]:
    """Train ``row``'s model for ``seed`` (built by ``build``, a
    :class:`~hnn_pl.experiments.collect.Build`) and score it (:func:`scores`); never
    raises (``error`` holds the traceback). ``train_s``: the fit; ``eval_s``: the scores."""
    record: dict[str, Any] = {**row._asdict(), "seed": seed}
    try:
        import torch

        config, swap = config_of(row)
        record["config"] = config
        if swap:
            record["options"] = list(swap)
        options = [f"--seed_everything={seed}", *swap]
        options += [f"--trainer.max_steps={max_steps}"] if max_steps else []
        cli = build(config, options)
        torch.set_num_threads(1)
        expected = CLASSES[row.model].rsplit(".", 1)[1]
        if type(cli.model).__name__ != expected:
            raise TypeError(f"{config} builds {type(cli.model).__name__}, not {expected}")
        dm = cli.datamodule
        dm.prepare_data()
        dm.setup("fit")
        t0 = time.perf_counter()
        cli.trainer.fit(cli.model, dm)
        record["train_s"] = time.perf_counter() - t0
        record["steps"] = cli.trainer.global_step
        record["chart"] = chart_of(cli.model)
        dm.setup("test")
        t0 = time.perf_counter()
        record.update(scores(row.task, cli.model.eval(), dm))
        record["eval_s"] = time.perf_counter() - t0
    except Exception:  # noqa: BLE001 - one failed run must not lose the others
        record["error"] = traceback.format_exc()
    return record


def chart_of(model: Any) -> str | None:
    """The system a velocity model reads the ``(q, p)`` data through (its class name),
    ``None`` for a model on the data's own coordinates.

    Raises:
        RuntimeError: a velocity model without a chart (it would read ``p`` as ``q̇``).
    """
    if getattr(model, "coordinates", None) != "velocity":
        return None
    if model.chart is None:
        raise RuntimeError(f"{type(model).__name__} has no chart: the data gave no system")
    return type(model.chart.system).__name__


def scores(task: str, model: Any, dm: Any) -> dict[str, float]:
    """A trained model's scores on ``dm`` (after ``setup("test")``): on a chain task the
    medians over the test trajectories of its relative rollout error and of the chaos
    floor (the mean of the middle two of an even count, as the published medians); on a
    state task the clean protocol's ``energy_mse`` and ``state_mse``."""
    if task in CHAIN_TASKS:
        return {
            "rollout_error": float(dm.rollout_errors(model).quantile(0.5)),
            "chaos_floor": chaos_floor_median(dm),
        }
    from hnn_pl.evaluation import evaluate, task_protocol

    metrics, _ = evaluate(model, dm, task_protocol(task, "clean"))
    return {k: metrics.get(k) for k in STATE_SCORES}


#: the chaos floors' medians computed in this process, by the data's cache parameters
_FLOORS: dict[str, float] = {}


def chaos_floor_median(dm: Any) -> float:
    """The median over ``dm``'s test trajectories of its chaos floor (the true system's,
    the same for every model): computed once per data set in a process, so a campaign's
    rows on one data set share it."""
    key = json.dumps(dm.cache_params(), sort_keys=True, default=str)
    if key not in _FLOORS:
        _FLOORS[key] = float(dm.chaos_floor().quantile(0.5))
    return _FLOORS[key]


def collect(
    jobs: list[tuple[Row, int]],
    workers: int,
    max_steps: int | None,
    build: Any,
    done: Callable[[dict], None],
) -> None:
    """Run every ``(row, seed)`` of ``jobs`` with :func:`run_row` in ``workers``
    processes (0: in this one), ``done(record)`` as each finishes."""
    if workers == 0:
        for k, (row, seed) in enumerate(jobs, 1):
            done(_announced(k, len(jobs), row, seed, max_steps, build))
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from multiprocessing import get_context

    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        futures = [
            pool.submit(_announced, k, len(jobs), row, seed, max_steps, build)
            for k, (row, seed) in enumerate(jobs, 1)
        ]
        for future in as_completed(futures):
            done(future.result())


def _announced(
    k: int, n: int, row: Row, seed: int, max_steps: int | None, build: Any
) -> dict[str, Any]:
    from hnn_pl.experiments.collect import quiet_lightning_runs

    print(f"[start {k}/{n}] {row.task} {row.data} {row.model} seed {seed}", flush=True)
    with quiet_lightning_runs():
        return run_row(row, seed, max_steps, build)


def summarise(records: list[dict]) -> list[dict]:
    """One entry per row, in the records' order: each score's ``(median, worst)`` over
    the seeds that ran (worst: the largest), ``train_s``'s median, ``seeds`` and
    ``failed`` counts."""
    groups: dict[Row, list[dict]] = {}
    for r in records:
        groups.setdefault(Row(r["task"], r["data"], r["model"]), []).append(r)
    out = []
    for row, runs in groups.items():
        ok = [r for r in runs if "error" not in r]
        entry: dict[str, Any] = {**row._asdict(), "seeds": len(ok), "failed": len(runs) - len(ok)}
        for key in (*STATE_SCORES, *CHAIN_SCORES, "train_s"):
            values = [r[key] for r in ok if r.get(key) is not None]
            if values:
                entry[key] = (statistics.median(values), max(values))
        out.append(entry)
    return sorted(out, key=_order)


def _order(entry: dict) -> tuple:
    """Tasks in :data:`TASKS` order, data in :data:`DATA` order, models in :data:`MODELS`'."""
    task, data, model = entry["task"], entry["data"], entry["model"]
    return (TASKS.index(task), list(DATA[task]).index(data), MODELS.index(model))


#: the markers around the page's tables (the docs include what lies between)
TABLE_START, TABLE_END = "<!-- priors:table -->", "<!-- /priors:table -->"


def render(records: list[dict], meta: dict) -> str:
    """``RESULTS_priors.md`` from the JSON records and their ``meta`` (a function of
    them alone): the tables (between :data:`TABLE_START` and :data:`TABLE_END`), the
    published numbers, the targets, the per-seed values and the failed runs."""
    summary = summarise(records)
    lines = [
        "# Results: choosing a prior",
        "",
        f"`{meta['command']}` ({meta['machine']}; {meta['wall_s']:.0f} s).",
        "",
        TABLE_START,
        *_intro(meta),
        *_state_table(summary),
        *_chain_table(summary),
        TABLE_END,
        *_published(),
        *_targets(summary),
        *_per_seed(records),
        *_failures(records),
    ]
    return "\n".join(lines) + "\n"


def _intro(meta: dict) -> list[str]:
    lines = []
    if meta.get("max_steps"):
        lines += [
            f"**Smoke run: every run stopped after {meta['max_steps']} optimiser steps "
            "(`--max-steps`). These numbers test the pipeline; they say nothing of the "
            "priors.**",
            "",
        ]
    lines += [
        "Median (worst) over seeds; every model on the same data of each seed and scored "
        "the same way. State tasks: the fast recipe (`TASK_fast.yaml`, each model's class "
        "swapped in where it has no config of its own), the clean protocol's energy and "
        "state MSE. Chain pendulums (2 and 3 links): the constrained-HNN benchmark on "
        "`(θ, p)` data, the median over its 100 test trajectories of the relative rollout "
        "error in Cartesian coordinates, beside a published model of the same structure "
        "trained on `(θ, θ̇)` (2 links; their HNN and DeLaN already have the mass-matrix "
        "structure) and the chaos floor.",
        "",
    ]
    return lines


def _cell(entry: dict, key: str) -> str:
    if key not in entry:
        return "—"
    median, worst = entry[key]
    if key == "train_s":
        return f"{median:.3g}"
    return f"{median:.2e} ({worst:.2e})"


def _state_table(summary: list[dict]) -> list[str]:
    found = [e for e in summary if e["task"] in STATE_TASKS]
    if not found:
        return []
    lines = [
        "| task | model | seeds | energy MSE | state MSE | train s |",
        "|---|---|---|---|---|---|",
    ]
    for e in found:
        cells = [e["task"], e["model"], _seeds(e), *(_cell(e, k) for k in STATE_SCORES)]
        lines.append("| " + " | ".join([*cells, _cell(e, "train_s")]) + " |")
    return [*lines, ""]


def _chain_table(summary: list[dict]) -> list[str]:
    found = [e for e in summary if e["task"] in CHAIN_TASKS]
    if not found:
        return []
    lines = [
        "| task | data | model | seeds | rollout error | published, for comparison | train s |",
        "|---|---|---|---|---|---|---|",
    ]
    for e in found:
        name = COUNTERPART[e["model"]]
        published = "—"
        if e["task"] == PUBLISHED_TASK:
            published = f"{PUBLISHED[_chunks(e['data'])][name]:.2e} ({name})"
        cells = [e["task"], e["data"], e["model"], _seeds(e), _cell(e, "rollout_error")]
        cells += [published, _cell(e, "train_s")]
        lines.append("| " + " | ".join(cells) + " |")
    floors = [
        f"{task} {floor:.2e}, published {PUBLISHED_FLOORS[task]:.2e}"
        for task, floor in _floors(summary).items()
    ]
    if floors:
        lines += [
            "",
            "Chaos floor (the true system from starts perturbed by 1e-4; one test set per "
            "task, so one value for every row of it): " + "; ".join(floors) + ".",
        ]
    return [*lines, ""]


def _floors(summary: list[dict]) -> dict[str, float]:
    """Chain task → the median over its rows of their chaos floors (the tasks measured)."""
    floors: dict[str, list[float]] = {}
    for e in summary:
        if "chaos_floor" in e:
            floors.setdefault(e["task"], []).append(e["chaos_floor"][0])
    return {task: statistics.median(values) for task, values in floors.items()}


def _seeds(entry: dict) -> str:
    return f"{entry['seeds']}" + (f" ({entry['failed']} failed)" if entry["failed"] else "")


def _chunks(data: str) -> int:
    return int(data.split()[0])


def _published() -> list[str]:
    names = list(PUBLISHED[800])
    lines = [
        "",
        "## Published numbers",
        "",
        f"{SOURCE}. Their HNN already has the mass-matrix structure "
        "(`H = ½ pᵀ M_θ(θ)⁻¹ p + V_θ(θ)`) and DeLaN is its Lagrangian twin; CHNN and CLNN "
        "are the constrained models in Cartesian coordinates.",
        "",
        "| chunks | " + " | ".join(names) + " | chaos floor |",
        "|---" * (len(names) + 2) + "|",
    ]
    for chunks, values in PUBLISHED.items():
        cells = [f"{values[n]:.2e}" for n in names] + [f"{PUBLISHED_FLOOR:.2e}"]
        lines.append(f"| {chunks} | " + " | ".join(cells) + " |")
    return lines


def _targets(summary: list[dict]) -> list[str]:
    """Each target of :data:`TARGETS` and :data:`TIME_TARGETS` with the measured median
    (:func:`_verdict`), and the chaos floor's."""
    chain = {(_chunks(e["data"]), e["model"]): e for e in summary if e["task"] == PUBLISHED_TASK}
    if not chain:
        return []
    lines = ["", f"## Targets ({PUBLISHED_TASK}, medians)", ""]
    kinds = (
        (TARGETS, "rollout_error", "", "{:.2e}"),
        (TIME_TARGETS, "train_s", ", training time", "{:.0f} s"),
    )
    for targets, key, what, number in kinds:
        for chunks, model, bound, why in targets:
            e = chain.get((chunks, model), {})
            if key in e:
                value, verdict = _verdict(e, key, bound)
                lines.append(
                    f"- {chunks} chunks, {model}{what}: {number.format(value)} (target ≤ "
                    f"{number.format(bound)}, {why}): {verdict}"
                )
    floor = _floors(list(chain.values())).get(PUBLISHED_TASK)
    if floor is not None:
        off = abs(floor / PUBLISHED_FLOOR - 1)
        verdict = "met" if off <= FLOOR_TOLERANCE else "not met"
        lines.append(
            f"- chaos floor: {floor:.2e}, {off:.0%} from the published {PUBLISHED_FLOOR:.2e} "
            f"(target ≤ {FLOOR_TOLERANCE:.0%}): {verdict}"
        )
    return lines


def _verdict(entry: dict, key: str, bound: float) -> tuple[float, str]:
    """``entry``'s median of ``key`` and whether it is within ``bound`` (and over how many
    of the :data:`TARGET_SEEDS` seeds, when fewer)."""
    value = entry[key][0]
    verdict = "met" if value <= bound else "not met"
    if entry["seeds"] < TARGET_SEEDS:
        verdict += f" over {entry['seeds']} of {TARGET_SEEDS} seeds"
    return value, verdict


def _per_seed(records: list[dict]) -> list[str]:
    """``| task | data | model | seed 0 | … |``: the rollout error (chain) or energy MSE /
    state MSE (state tasks), ``failed`` for a failed run."""
    seeds = sorted({r["seed"] for r in records})
    lines = [
        "",
        "## Per seed",
        "",
        "Chain pendulum: the rollout error; state tasks: energy MSE / state MSE.",
        "",
        "| task | data | model | " + " | ".join(f"seed {s}" for s in seeds) + " |",
        "|---" * (3 + len(seeds)) + "|",
    ]
    cells: dict[Row, dict[int, str]] = {}
    for r in records:
        cells.setdefault(Row(r["task"], r["data"], r["model"]), {})[r["seed"]] = _seed_cell(r)
    for row in sorted(cells, key=lambda row: _order(row._asdict())):
        values = [cells[row].get(s, "") for s in seeds]
        lines.append("| " + " | ".join([*row, *values]) + " |")
    return lines


def _seed_cell(record: dict) -> str:
    if "error" in record:
        return "failed"
    keys = CHAIN_SCORES[:1] if record["task"] in CHAIN_TASKS else STATE_SCORES
    return " / ".join(_number(record.get(k)) for k in keys)


def _number(value: float | None) -> str:
    return "—" if value is None or math.isnan(value) else f"{value:.2e}"


def _failures(records: list[dict]) -> list[str]:
    failed = [r for r in records if "error" in r]
    if not failed:
        return []
    lines = ["", "## Failed runs", ""]
    for r in failed:
        last = r["error"].strip().splitlines()[-1]
        lines.append(f"- {r['task']} {r['data']} {r['model']} seed {r['seed']}: `{last}`")
    return lines


def write(records: list[dict], meta: dict, out: Path, json_path: Path) -> None:
    """The records to ``json_path`` and their page (:func:`render`) to ``out``, each
    atomically."""
    from hnn_pl.safe_io import write_atomic

    for path in (out, json_path):
        path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(json_path, json.dumps({"meta": meta, "runs": records}, indent=1).encode())
    write_atomic(out, render(records, meta).encode())


def run(call: Any, build: Any) -> int:
    """The campaign of a ``reproduce`` call (:class:`hnn_pl.experiments.reproduce.Call`:
    its ``tasks``, ``models``, ``chunks``, ``seeds``, ``workers``, ``max_steps``, ``out``,
    ``json_path``, ``command``), runs made by ``build``: the page and the JSON records
    written as each run finishes. Exit status 0, 1 if a run failed."""
    from hnn_pl.experiments.collect import machine

    jobs = [(row, s) for row in rows(call.tasks, call.models, call.chunks) for s in call.seeds]
    start = time.perf_counter()
    meta = {
        "recipe": "priors",
        "command": call.command,
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d"),
        "max_steps": call.max_steps,
        "workers": call.workers,
        "wall_s": 0.0,
    }
    records: list[dict] = []

    def done(record: dict) -> None:
        records.append(record)
        meta["wall_s"] = time.perf_counter() - start
        write(records, meta, call.out, call.json_path)
        status = "FAILED" if "error" in record else "done"
        print(
            f"[{status} {len(records)}/{len(jobs)}, {meta['wall_s']:.0f} s] "
            f"{record['task']} {record['data']} {record['model']} seed {record['seed']}",
            flush=True,
        )

    print(f"{len(jobs)} runs on {max(call.workers, 1)} worker(s)", flush=True)
    collect(jobs, call.workers, call.max_steps, build, done)
    print(f"wrote {call.out} and {call.json_path}")
    return 1 if any("error" in r for r in records) else 0
