"""Collect, the first step of ``reproduce``: train and evaluate runs, one record each.

Every task × model × seed is trained from its bundled config (the same YAML ``fit``
uses, so the settings are the paper's), then evaluated with the protocols of
:mod:`hnn_pl.evaluation`. Runs go to a pool of worker processes with one torch thread
each (on 2 cores two single-threaded runs beat one two-threaded run). Each seed
(``seed_everything``) draws its own initialisation and, as in the reference code, its
own data set. A run is built by the :class:`Build` the command hands in (the CLI's
:func:`hnn_pl.commands.cli.quiet_run`): this layer never imports the commands.
"""

from __future__ import annotations

import os
import platform
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Protocol

from hnn_pl import tasks
from hnn_pl.experiments import paper

#: one run: ``(task, model, seed)``
Job = tuple[str, str, int]


class Build(Protocol):
    """Builds a run of a bundled ``config`` plus command-line ``options``, quiet (no
    logger, checkpoints, progress bar, callbacks or validation) and not started: an
    object with ``model``, ``datamodule`` and ``trainer``
    (:func:`hnn_pl.commands.cli.quiet_run`)."""

    def __call__(
        self, config: str, options: Sequence[str] = (), save_config: bool = False
    ) -> Any: ...


def machine() -> str:
    """``x86_64, 2 cores, AVX2 kernels, Python 3.11.7``: what a run's numbers depend on."""
    import torch

    return (
        f"{platform.machine()}, {os.cpu_count()} cores, "
        f"{torch.backends.cpu.get_cpu_capability()} kernels, Python {platform.python_version()}"
    )


def _options(seed: int, max_steps: int | None) -> list[str]:
    """The command-line options of one seed (and a step count other than the config's)."""
    steps = [] if max_steps is None else [f"--trainer.max_steps={max_steps}"]
    return [f"--seed_everything={seed}", *steps]


def run_one(
    task: str,
    model: str,
    seed: int,
    max_steps: int | None = None,
    recipe: str = "paper",
    overrides: tuple[str, ...] = (),
    model_path: str | None = None,
    tta: bool = True,
    *,
    build: Build,
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
    with quiet_lightning_runs():
        return _run_one(record, build, max_steps, recipe, overrides, model_path, tta)


def _run_one(
    record: dict,
    build: Build,
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
        from hnn_pl.evaluation import evaluate_task
        from hnn_pl.experiments.tta import TimeToAccuracy

        config = paper.get(task).config(model, recipe)
        cli = build(config, _options(seed, max_steps) + list(overrides))
        torch.set_num_threads(1)
        cli.datamodule.prepare_data()
        cli.datamodule.setup("fit")
        tta = None
        if measure_tta:
            tta = TimeToAccuracy(task, every_n_steps=paper.get(task).tta_every[recipe])
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
def quiet_lightning_runs() -> Iterator[None]:
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


def _started(job: Job, k: int, n: int, **kwargs) -> dict:
    """:func:`run_one` after printing ``[start k/n] task model seed s``."""
    print(f"[start {k}/{n}] {job[0]} {job[1]} seed {job[2]}", flush=True)
    return run_one(*job, **kwargs)


def remaining(jobs: list[Job], done: list[Job], elapsed: float) -> str:
    """``, ~T s left``: the elapsed time scaled by the remaining runs' share of the
    tasks' relative costs (:attr:`hnn_pl.experiments.paper.PaperTask.cost`)."""
    cost = {j: paper.get(j[0]).cost for j in jobs}
    spent = sum(cost[j] for j in done)
    if not spent:
        return ""
    left = elapsed * (sum(cost.values()) - spent) / spent
    return f", ~{left:.0f} s left" if left > 0 else ""


def _trained(task: str, model: str, seed: int, recipe: str, path: Path, build: Build) -> Any:
    """The model and data module of a finished run, the model's weights from ``path``."""
    import torch

    cli = build(paper.get(task).config(model, recipe), _options(seed, None))
    cli.model.load_state_dict(torch.load(path, weights_only=True))
    return cli.model, cli.datamodule


def through_hnn(task: str) -> bool:
    """Whether ``task``'s reference protocol reads every model through the HNN's encoder."""
    return tasks.get(task).reference.fields.get("probe_encoder") == "hnn"


def probe_through_hnn(
    records: list[dict], paths: dict[tuple, Path], recipe: str, build: Build
) -> None:
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
        if not through_hnn(task) or record.get("reference_probe"):
            continue
        record["reference_probe"] = "own"
        hnn_key = (task, "hnn", seed)
        if model == "hnn" or hnn_key not in ok:
            continue
        if (task, model, seed) not in paths or hnn_key not in paths:
            continue
        net, dm = _trained(task, model, seed, recipe, paths[task, model, seed], build)
        hnn, _ = _trained(task, "hnn", seed, recipe, paths[hnn_key], build)
        dm.prepare_data()
        dm.setup("test")
        record["reference_own_encoder"] = record["reference"]
        again = evaluate_task(task, net, dm, hnn, protocols=("reference",), losses=False)
        record["reference"] = again["reference"]
        record["reference_probe"] = "hnn"


def prepare_data(jobs: list[Job], recipe: str, build: Build) -> dict[str, float]:
    """Generate every job's data once, before the workers start; seconds per task."""
    times: dict[str, float] = {}
    for task, model, seed in jobs:
        cli = build(paper.get(task).config(model, recipe), _options(seed, None))
        t0 = time.perf_counter()
        cli.datamodule.prepare_data()
        times[task] = times.get(task, 0.0) + time.perf_counter() - t0
    return times


def run_jobs(
    jobs: list[Job],
    workers: int,
    done: Callable[[dict], None],
    paths: dict[tuple, Path],
    **kwargs: Any,
) -> None:
    """Run every job with :func:`run_one` (``kwargs``: its options, ``build`` among
    them; in this process for ``workers=0``), ``done(record)`` as each finishes. Workers
    ignore Ctrl-C and die with this process (:func:`_die_with_parent`); on Ctrl-C or a
    dead worker the others are killed and the pool shut down before the error goes on
    (:func:`_stop`); a Ctrl-C while the pool starts is raised once it has started
    (:func:`_ctrl_c_held`)."""
    if workers == 0:
        for k, job in enumerate(jobs, 1):
            done(_started(job, k, len(jobs), **kwargs, model_path=paths.get(job)))
        return
    pool = None
    try:
        with _ctrl_c_held():
            pool = ProcessPoolExecutor(
                workers,
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
    """Kill ``pool``'s workers and wait for its manager thread to wind down: not waiting
    leaves that thread closing its wake-up pipe while the interpreter's exit hook writes
    to it (``OSError: [Errno 9] Bad file descriptor`` at exit, under load); with the
    workers dead it ends at once."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.kill()
    pool.shutdown(wait=True, cancel_futures=True)


@contextmanager
def _ctrl_c_held() -> Iterator[None]:
    """Ctrl-C (SIGINT) while the worker pool starts, raised as ``KeyboardInterrupt``
    once it has started: an interrupt inside multiprocessing's launch of a worker leaves
    a worker the pool does not know, or its pipes half made. SIGINT is recorded and
    blocked meanwhile; a worker spawned now starts with it blocked until
    :func:`_die_with_parent` ignores and unblocks it (the resource tracker is started
    first: its start unblocks SIGINT in this thread). Main thread only."""
    import signal
    import threading

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
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def _die_with_parent(parent: int) -> None:
    """In a worker: ignore Ctrl-C (the parent stops the pool) and die with the parent,
    by ``PR_SET_PDEATHSIG`` on Linux and a thread watching ``os.getppid()`` anywhere,
    so a killed ``reproduce`` leaves no worker (nor, with its pipes closed, the
    multiprocessing resource tracker) behind."""
    import signal
    import threading

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
