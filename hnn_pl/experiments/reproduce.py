"""``python -m hnn_pl reproduce``: the paper's Table 1, trained and evaluated here.

Three steps: :mod:`~hnn_pl.experiments.collect` trains and evaluates every selected
task × model × seed (one record per run), :mod:`~hnn_pl.experiments.summary` takes the
median and worst over seeds, :mod:`~hnn_pl.experiments.results` writes ``RESULTS.md``.
Each finished run is written to the JSON file at once, so a failed or interrupted run
loses nothing else, and ``RESULTS.md`` is rewritten from it. Spreads over seeds
include data variance (each seed draws its own data set, as in the reference code).

This module declares the command's options (:func:`parse`) and runs a call
(:func:`run`); ``hnn_pl.commands.reproduce`` is its command line.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import tempfile
import time
import uuid
from argparse import ArgumentParser, Namespace
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

from hnn_pl.argtypes import non_negative_int, positive_int
from hnn_pl.experiments import collect, paper, priors
from hnn_pl.experiments.collect import Build, Job
from hnn_pl.experiments.results import write_markdown


@dataclass(frozen=True)
class Call:
    """One call of ``reproduce``: its runs, how they train, where the records go.

    Attributes:
        jobs: the runs, ``(task, model, seed)``, in the order they start.
        recipe: ``"paper"``, ``"fast"`` or ``"traj"``: which bundled configs;
            ``"positions"``: the campaign of :mod:`hnn_pl.experiments.positions` (which
            reads ``tasks``, ``seeds``, ``workers``, ``max_steps`` and ``out``; no ``jobs``);
            ``"priors"``: the campaign of :mod:`hnn_pl.experiments.priors` (which also
            reads ``models`` and ``chunks``; no ``jobs``).
        tasks, seeds: the tasks asked for (``None``: the recipe's default) and seeds.
        models: the models asked for (``None``: the recipe's default).
        chunks: the chain pendulum's training chunks (recipe ``"priors"``).
        out, json_path: ``RESULTS.md`` and the raw records.
        workers: processes (0: in this process).
        max_steps: every run's steps (``None``: the config's).
        tta: whether runs measure time to accuracy.
        merge: keep the runs of ``json_path`` that this call does not redo.
        models_dir: where the pixel runs' weights are kept (``None``: a temporary folder).
        prog, command: the program's name and the command line (``prog`` and the
            arguments), for the report.
    """

    jobs: list[Job]
    recipe: str
    out: Path
    json_path: Path
    tasks: list[str] | None = None
    models: list[str] | None = None
    chunks: tuple[int, ...] = priors.DEFAULT_CHUNKS
    seeds: range = range(3)
    workers: int = 2
    max_steps: int | None = None
    tta: bool = True
    merge: bool = False
    models_dir: Path | None = None
    prog: str = "python -m hnn_pl reproduce"
    command: str = ""


def add_arguments(parser: ArgumentParser) -> None:
    """The options of ``reproduce``: which runs (:func:`_run_arguments`), then how and
    where."""
    _run_arguments(parser)
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


def _run_arguments(parser: ArgumentParser) -> None:
    """The options that choose the runs: tasks, models, recipe, seeds."""
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=None,
        choices=[*paper.PAPER, *PRIORS_ONLY],
        help="default: the state tasks (recipe traj: those with traj configs; recipe priors: "
        "spring pendulum chain2 chain3); add pixel explicitly; chain2 and chain3 run in "
        "recipe priors (the default recipe when one is named)",
    )
    parser.add_argument(
        "--models",
        nargs="+",
        default=None,
        choices=[*paper.MODELS, *(m for m in priors.MODELS if m not in paper.MODELS)],
        help="default: baseline hnn (recipe priors: all but dissipative); dissipative runs "
        "where a task has it (real_pendulum), mechanical_hnn_fast (a recipe of the "
        "structured HNN) where its config is (chain2, 800 chunks)",
    )
    parser.add_argument(
        "--recipe",
        default=None,
        choices=(*paper.RECIPES, "positions", "priors"),
        help="paper (the default; priors when --tasks names a chain): the paper's settings "
        "(TASK.yaml); fast: the fast recipes (TASK_fast.yaml); "
        "traj: learning from the observed states only, trajectory objective (TASK_traj.yaml); "
        "positions: from positions alone (TASK_positions*.yaml) beside the states-only and "
        "finite-difference fits, scored through the observer (RESULTS_positions.md); "
        "priors: every model (baseline, HNN, LNN and the mass-matrix-structured pair) on "
        "the state tasks' fast recipes and the chain pendulums (RESULTS_priors.md)",
    )
    parser.add_argument(
        "--chunks",
        nargs="+",
        type=int,
        default=None,
        choices=priors.CHUNKS,
        help="recipe priors: the chain pendulum's training chunks (default: 100; 800 is the "
        "benchmark's large set, chainN.yaml)",
    )
    parser.add_argument("--seeds", type=positive_int, default=3, help="number of seeds (0, 1, …)")
    parser.add_argument(
        "--first-seed",
        type=non_negative_int,
        default=0,
        help="start at this seed (extend a --merge run)",
    )


#: the tasks only the priors campaign measures
PRIORS_ONLY = tuple(t for t in priors.TASKS if t not in paper.PAPER)


def parse(parser: ArgumentParser, argv: list[str] | None = None) -> Call:
    """The :class:`Call` that ``argv`` asks for (``None``: ``sys.argv[2:]``); bad input
    goes to ``parser.error`` before anything is made."""
    add_arguments(parser)
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    _choose_recipe(parser, args)
    if args.recipe == "priors":
        out = Path(args.out) if args.out else _new_run_dir("priors") / "RESULTS_priors.md"
        json_path = Path(args.json) if args.json else out.with_suffix(".json")
        _check_files(parser, out, json_path)
        return _call(parser, argv, args, [], out, seeds, json_path)
    if args.recipe == "positions":
        return _call(parser, argv, args, [], Path(args.out or "RESULTS_positions.md"), seeds)
    if args.models is None:
        args.models = ["baseline", "hnn"]
    if args.tasks is None:
        args.tasks = paper.TRAJ_TASKS if args.recipe == "traj" else paper.DEFAULT_TASKS
    out = Path(args.out) if args.out else _new_run_dir(args.recipe) / "RESULTS.md"
    json_path = Path(args.json) if args.json else out.with_suffix(".json")
    _check_files(parser, out, json_path)
    jobs = paper.jobs(args.tasks, args.models, args.recipe, seeds)
    if not jobs:
        parser.error(f"no task of {args.tasks} has a model of {args.models}")
    return _call(parser, argv, args, jobs, out, seeds, json_path)


def _choose_recipe(parser: ArgumentParser, args: Namespace) -> None:
    """``args.recipe`` settled (``priors`` when ``--tasks`` names only its tasks and no
    recipe is given, else ``paper``) and checked against the tasks, models and chunks."""
    only = [t for t in args.tasks or [] if t in PRIORS_ONLY]
    if args.recipe is None:
        if only and any(t not in priors.TASKS for t in args.tasks):
            parser.error(
                f"--tasks {' '.join(only)} runs in --recipe priors, which has no "
                f"{' '.join(t for t in args.tasks if t not in priors.TASKS)}"
            )
        args.recipe = "priors" if only else "paper"
    if args.recipe != "priors":
        if only:
            parser.error(f"--tasks {' '.join(only)} runs in --recipe priors only")
        if args.chunks is not None:
            parser.error("--chunks belongs to --recipe priors")
        return
    for option, given, known in (
        ("--tasks", args.tasks, priors.TASKS),
        ("--models", args.models, priors.MODELS),
    ):
        unknown = [x for x in given or [] if x not in known]
        if unknown:
            parser.error(f"{option} {' '.join(unknown)}: --recipe priors runs {', '.join(known)}")
    if args.merge:
        parser.error("--merge belongs to the paper, fast and traj recipes")
    args.chunks = tuple(sorted(set(args.chunks or priors.DEFAULT_CHUNKS)))


def _check_files(parser: ArgumentParser, out: Path, json_path: Path) -> None:
    """``--out`` and ``--json`` name files that can be written (else ``parser.error``)."""
    for option, path in (("--out", out), ("--json", json_path)):
        if path.is_dir():
            parser.error(f"{option} {path} is a directory; name the file to write")
        if path.parent.exists() and not path.parent.is_dir():
            parser.error(f"{option} {path}: {path.parent} is not a directory")


def _call(
    parser: ArgumentParser,
    argv: list[str] | None,
    args: Namespace,
    jobs: list[Job],
    out: Path,
    seeds: range,
    json_path: Path | None = None,
) -> Call:
    return Call(
        jobs=jobs,
        recipe=args.recipe,
        out=out,
        json_path=out.with_suffix(".json") if json_path is None else json_path,
        tasks=args.tasks,
        models=args.models,
        chunks=args.chunks or priors.DEFAULT_CHUNKS,
        seeds=seeds,
        workers=args.workers,
        max_steps=args.max_steps,
        tta=not args.no_tta,
        merge=args.merge,
        models_dir=None if args.models_dir is None else Path(args.models_dir),
        prog=parser.prog,
        command=f"{parser.prog} " + " ".join(argv or sys.argv[2:]),
    )


def _new_run_dir(recipe: str) -> Path:
    """``results/<recipe>-<YYYYmmdd-HHMMSS>[-k]``, a folder that does not exist yet."""
    base = Path("results") / f"{recipe}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, k = base, 1
    while path.exists():
        path, k = base.with_name(f"{base.name}-{k}"), k + 1
    return path


def run(call: Call, build: Build) -> int:
    """Prepare every run's data, train and evaluate the runs (:mod:`collect`), write the
    records and ``RESULTS.md`` as each finishes. Exit status: 0, 1 if a run failed, 130
    on Ctrl-C, 2 if a worker died. The ``positions`` and ``priors`` recipes are
    :func:`hnn_pl.experiments.positions.run` and :func:`hnn_pl.experiments.priors.run`."""
    if call.recipe == "priors":
        return priors.run(call, build)
    if call.recipe == "positions":
        from hnn_pl.experiments import positions

        return positions.run(call, build)
    start = time.perf_counter()
    with collect.quiet_lightning_runs():
        data_s = collect.prepare_data(call.jobs, call.recipe, build)
    records, earlier = _kept_runs(call)
    progress = _Progress(call, _meta(call, data_s, earlier if records else None), records, start)
    keep = call.models_dir is not None
    model_dir = call.models_dir if keep else Path(tempfile.mkdtemp(prefix="hnn_pl_models_"))
    model_dir.mkdir(parents=True, exist_ok=True)
    paths = {j: _weights(model_dir, j, call.recipe) for j in call.jobs if collect.through_hnn(j[0])}
    try:
        print(
            f"{len(call.jobs)} runs on {progress.meta['workers']} worker(s); "
            f"data ready in {sum(data_s.values()):.1f} s",
            flush=True,
        )
        options = {"max_steps": call.max_steps, "recipe": call.recipe, "tta": call.tta}
        collect.run_jobs(call.jobs, call.workers, progress.done, paths, **options, build=build)
        if paths:
            hnns = [(t, "hnn", s) for t, _, s in paths]
            weights = {**paths, **{j: _weights(model_dir, j, call.recipe) for j in hnns}}
            found = {j: p for j, p in weights.items() if p.exists()}
            collect.probe_through_hnn(records, found, call.recipe, build)
            write(records, progress.meta, call)
    except (KeyboardInterrupt, BrokenProcessPool) as err:
        return _interrupted(err, call, len(records) - progress.kept)
    finally:
        if not keep:
            shutil.rmtree(model_dir, ignore_errors=True)
    print(f"wrote {call.out} and {call.json_path} in {time.perf_counter() - start:.0f} s")
    return 1 if any("error" in r for r in records) else 0


def _weights(model_dir: Path, job: Job, recipe: str) -> Path:
    task, model, seed = job
    return model_dir / f"{task}_{model}_{seed}_{recipe}.pt"


def _kept_runs(call: Call) -> tuple[list[dict], list[dict]]:
    """With ``--merge``: the runs of the JSON file that this call does not redo, and the
    earlier calls that still own one of them."""
    if not (call.merge and call.json_path.exists()):
        return [], []
    redo = set(call.jobs)
    old = json.loads(call.json_path.read_text())
    records = [r for r in old["runs"] if (r["task"], r["model"], r["seed"]) not in redo]
    earlier = old["meta"].pop("earlier_calls", []) + [old["meta"]]
    return records, _contributing(earlier, records)


def _contributing(calls: list[dict], records: list[dict]) -> list[dict]:
    """The earlier calls that still own a kept run (runs are tagged with their call's
    ``id``); calls or runs written before tagging existed are all kept."""
    owners = {r.get("call") for r in records}
    return [c for c in calls if "id" not in c or None in owners or c["id"] in owners]


def _meta(call: Call, data_s: dict[str, float], earlier: list[dict] | None) -> dict:
    """The JSON file's ``meta``: this call's id, date, machine, command and settings."""
    meta = {
        "id": uuid.uuid4().hex,
        "date": time.strftime("%Y-%m-%d"),
        "machine": collect.machine(),
        "command": f"`{call.command}`",
        "workers": max(call.workers, 1),
        "recipe": call.recipe,
        "data_s": data_s,
    }
    if earlier is not None:
        meta["earlier_calls"] = earlier
    return meta


def write(records: list[dict], meta: dict, call: Call) -> None:
    """The records to ``call.json_path`` and ``RESULTS.md`` to ``call.out``, atomically."""
    from hnn_pl.safe_io import write_atomic

    call.out.parent.mkdir(parents=True, exist_ok=True)
    call.json_path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(call.json_path, json.dumps({"meta": meta, "runs": records}, indent=1).encode())
    write_markdown(records, call.out, meta)


class _Progress:
    """Each finished run: tagged with the call, written at once (:func:`write`), and
    one line ``[done k/n, T s, ~L s left] task model seed s: numbers``."""

    def __init__(self, call: Call, meta: dict, records: list[dict], start: float) -> None:
        self.call, self.meta, self.records, self.start = call, meta, records, start
        self.kept = len(records)
        self.finished: list[Job] = []
        self.run_start = time.perf_counter()

    def done(self, record: dict) -> None:
        self.finished.append((record["task"], record["model"], record["seed"]))
        record["call"] = self.meta["id"]
        self.records.append(record)
        self.meta["total_s"] = time.perf_counter() - self.start
        write(self.records, self.meta, self.call)
        elapsed = time.perf_counter() - self.run_start
        left = collect.remaining(self.call.jobs, self.finished, elapsed)
        print(
            f"[done {len(self.records) - self.kept}/{len(self.call.jobs)}, "
            f"{self.meta['total_s']:.0f} s{left}] "
            f"{record['task']} {record['model']} seed {record['seed']}: {_status(record)}",
            flush=True,
        )


def _status(record: dict) -> str:
    """A finished run's numbers in one line, or ``FAILED:`` and its error's last line."""
    if "error" in record:
        return "FAILED: " + record["error"].strip().splitlines()[-1]
    clean = record["clean"]
    return (
        f"train {record['train_s']:.1f} s, eval {record['eval_s']:.1f} s, test loss "
        f"{record['test_loss']:.3e}, energy MSE ref {record['reference']['energy_mse']:.3e} "
        f"clean {clean['energy_mse']:.3e}, state MSE "
        f"{clean.get('state_mse', math.nan):.3e}, field error "
        f"{clean.get('field_error', math.nan):.3e}"
    )


def _interrupted(err: BaseException, call: Call, finished: int) -> int:
    """One line on stderr for Ctrl-C (status 130) or a dead worker (2): how many runs
    finished and where they are kept."""
    interrupted = isinstance(err, KeyboardInterrupt)
    what = "interrupted" if interrupted else "a worker process died (killed, or out of memory)"
    where = f"kept in {call.json_path} and {call.out}" if finished else "nothing written"
    print(
        f"{call.prog}: {what}: {finished} of {len(call.jobs)} runs finished, {where}",
        file=sys.stderr,
        flush=True,
    )
    return 130 if interrupted else 2
