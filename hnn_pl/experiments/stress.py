"""``python -m hnn_pl stress [--quick] [--out STABILITY.md]``: numerical stability.

Writes a Markdown report with its figures (in ``<out stem>/``):

1. **Long runs of the true systems** (mass-spring ``H = q² + p²``, pendulum
   ``H = 3(1 − cos q) + p²``), float64, ``10⁶`` fixed steps of ``h = 0.1`` (quick:
   2000): relative energy error ``|H(y_t) − H(y_0)| / H(y_0)`` per method, its
   least-squares slope in time, and its mean over the first and the last tenth of the
   run; symplectic methods stay bounded, ``rk4`` and ``dopri5`` drift.
2. **Trained models** (``spring_fast`` HNN and baseline): rollouts to 10× and 100× the
   training horizon (quick: 2×, 4×, 20 training steps, 5 starts) and from starts at 2×
   and 5× the training energy: rows that stay
   finite, true-energy error and the learned ``H_θ``'s drift per method.
3. **Hard cases**: two-body orbits down to a head-on collision (the adaptive method
   finishes each row or stops it with a status), a stiff van der Pol oscillator and an
   unreachable tolerance (both stop early, saying why).
4. **float32 against float64**, and **reversibility**: integrate to ``T`` and back,
   ``max |y_back − y_0|`` per method and dtype.
"""

from __future__ import annotations

import datetime
import math
import platform
import time
from argparse import ArgumentParser, Namespace
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from hnn_pl.evaluation import rollout
from hnn_pl.evaluation.metrics import drift_stats, h_drift, relative_energy_error, return_error
from hnn_pl.experiments.report import save_figure, table
from hnn_pl.integrate import Status, odeint
from hnn_pl.plotting import pyplot
from hnn_pl.systems import MassSpring, Pendulum, TwoBody

F32, F64 = torch.float32, torch.float64
#: fixed-step methods of the long runs and their options; dopri5 runs at rtol = 1e-6
LONG_METHODS = {
    "leapfrog": {"options": {"check_separable": False}},
    "implicit_midpoint": {"rtol": 1e-12, "atol": 1e-14},
    "rk4": {},
    "dopri5": {"rtol": 1e-6, "atol": 1e-9, "options": {"max_steps": 10**7}},
}
LONG_HEADER = ["system", "method", "max", "slope per unit t", "first tenth", "last tenth"]
LONG_HEADER += ["seconds", "µs per step"]
TRAINED_HEADER = ["setting", "model", "method", "finite rows", "median |ΔE| / E at the end"]
TRAINED_HEADER += ["max H_θ drift"]
STARTS = torch.tensor([[1.0, 0.0], [0.3, -0.6], [-0.5, 1.2]], dtype=F64)


def long_run(system: Any, method: str, n_steps: int, h: float = 0.1, dtype=F64) -> dict:
    """``n_steps`` steps of ``h`` of the true ``system`` from :data:`STARTS` (for
    ``dopri5``: the same horizon); the relative energy error at 1000 output times."""
    n_out = min(1000, n_steps)
    t = torch.linspace(0, n_steps * h, n_out + 1, dtype=dtype)
    kwargs = dict(LONG_METHODS[method])
    if method != "dopri5":
        kwargs["step_size"] = h
    y0 = STARTS.to(dtype)
    start = time.perf_counter()
    with torch.inference_mode():
        sol = odeint(system.vector_field, y0, t, method, return_status=True, **kwargs)
    seconds = time.perf_counter() - start
    rel = relative_energy_error(system.hamiltonian(sol.y.double()))
    stats = drift_stats(t.double(), rel)
    out = {"t": t.double(), "rel": rel, "seconds": seconds, "ok": bool(sol.ok.all())}
    return {**out, "n_steps": n_steps, **stats}


def reversibility(system: Any, method: str, dtype, t_end: float = 20.0, h: float = 0.05) -> float:
    """``max |y_back − y0|`` after integrating to ``t_end`` and back to 0."""
    kwargs = dict(LONG_METHODS[method])
    if method == "dopri5":
        kwargs = {"rtol": 1e-9 if dtype == F64 else 1e-6, "atol": 1e-12 if dtype == F64 else 1e-8}
        kwargs["options"] = {"max_steps": 10**7}
    else:
        kwargs["step_size"] = h
        if method == "implicit_midpoint" and dtype == F32:
            kwargs.update(rtol=1e-6, atol=1e-7)
    y0 = STARTS.to(dtype)
    t = torch.tensor([0.0, t_end], dtype=dtype)
    with torch.inference_mode():
        y1 = odeint(system.vector_field, y0, t, method, **kwargs)[-1]
        y_back = odeint(system.vector_field, y1, t.flip(0), method, **kwargs)[-1]
    return float(return_error(y_back, y0))


def hard_cases(quick: bool) -> list[list[str]]:
    """Two-body orbits of decreasing angular momentum down to a head-on collision, a
    stiff van der Pol oscillator, an unreachable float32 tolerance: rows of case,
    status, outcome, max relative energy error, seconds."""
    return [*_two_body_rows(), _van_der_pol_row(), _unreachable_tolerance_row()]


def _two_body_rows() -> list[list[str]]:
    """Two bodies at distance 2 with tangential speeds 1 … 0 × circular (0: head-on),
    one adaptive batch to t = 10: each row reaches the end or stops with a status."""
    system = TwoBody()
    factors = (1.0, 0.1, 0.01, 1e-3, 0.0)
    y0 = torch.zeros(len(factors), 8, dtype=F64)
    y0[:, 0], y0[:, 2] = 1.0, -1.0
    y0[:, 5] = 0.5 * torch.tensor(factors, dtype=F64)
    y0[:, 7] = -y0[:, 5]
    t = torch.linspace(0, 10.0, 101, dtype=F64)
    start = time.perf_counter()
    sol = odeint(system.vector_field, y0, t, rtol=1e-10, atol=1e-10, return_status=True)
    seconds = time.perf_counter() - start
    rows = []
    for f, code, t_stop in zip(factors, sol.status.tolist(), sol.t_stop.tolist(), strict=True):
        e = system.hamiltonian(sol.y[:, factors.index(f)])
        drift = float(relative_energy_error(e[torch.isfinite(e)]).max())
        where = "reached t = 10" if code == Status.OK else f"stopped at t = {t_stop:.4f}"
        rows.append(
            [
                f"two-body, tangential speed {f:g} × circular",
                Status(code).name.lower(),
                where,
                f"{drift:.1e}",
                f"{seconds:.2f} (whole batch)",
            ]
        )
    return rows


def _van_der_pol_row() -> list[str]:
    """A van der Pol oscillator at μ = 1000 (stiff): dopri5 stops early, saying why."""

    def vdp(t: Tensor, y: Tensor) -> Tensor:
        x, v = y[..., :1], y[..., 1:]
        return torch.cat([v, 1000 * (1 - x**2) * v - x], -1)

    start = time.perf_counter()
    sol = odeint(
        vdp, torch.tensor([[2.0, 0.0]], dtype=F64), torch.tensor([0.0, 3000.0]), return_status=True
    )
    seconds = time.perf_counter() - start
    return [
        "van der Pol μ = 1000, t ∈ [0, 3000], dopri5",
        Status(int(sol.status[0])).name.lower(),
        f"stopped at t = {float(sol.t_stop[0]):.3g}: {sol.describe().split('): ')[-1]}",
        "—",
        f"{seconds:.2f}",
    ]


def _unreachable_tolerance_row() -> list[str]:
    """A float32 run asked for rtol = atol = 1e-14: refused before it starts."""
    start = time.perf_counter()
    try:
        odeint(
            MassSpring().vector_field,
            STARTS.float(),
            torch.tensor([0.0, 20.0]),
            rtol=1e-14,
            atol=1e-14,
        )
        outcome = "ran (unexpected)"
    except ValueError as err:
        outcome = str(err).split(":")[1].strip()[:90] + "…"
    return [
        "float32 at rtol = atol = 1e-14, dopri5",
        "refused",
        outcome,
        "—",
        f"{time.perf_counter() - start:.3f}",
    ]


#: the trained models' methods and their options
TRAINED_METHODS = {
    "dopri5": {"rtol": 1e-9, "atol": 1e-9},
    "rk4": {"step_size": 0.05},
    "implicit_midpoint": {"step_size": 0.05, "rtol": 1e-10, "atol": 1e-12},
}


def _train_spring(quick: bool, build: Any) -> tuple[dict[str, Any], Any]:
    """``spring_fast`` HNN and baseline, trained (``quick``: 20 steps); their data module."""
    models, dm = {}, None
    for name in ("hnn", "baseline"):
        config = "spring_fast.yaml" if name == "hnn" else "spring_fast_baseline.yaml"
        options = ["--threads=1", *(["--trainer.max_steps=20"] if quick else [])]
        cli = build(config, options)
        cli.trainer.fit(cli.model, cli.datamodule)
        models[name], dm = cli.model, cli.datamodule
    return models, dm


def trained_models(quick: bool, build: Any) -> tuple[list[list[str]], dict, tuple[int, int]]:
    """Train ``spring_fast`` HNN and baseline (runs made by ``build``,
    :class:`hnn_pl.experiments.collect.Build`), roll them out far and from high energy."""
    models, dm = _train_spring(quick, build)
    t_train = float(dm.t_span[1] - dm.t_span[0])
    y0 = dm.rollout_target()[1][0].double()[: 5 if quick else None]
    rows, curves = [], {}
    far = (2, 4) if quick else (10, 100)
    settings = [(f"{k}× horizon", k * t_train, 1.0) for k in far]
    settings += [(f"{k}× energy", far[0] * t_train, float(k)) for k in (2, 5)]
    for label, t_end, energy in settings:
        t = torch.linspace(0, t_end, 501, dtype=F64)
        starts = y0 * math.sqrt(energy)
        for name, model in models.items():
            for method, kw in TRAINED_METHODS.items():
                out = rollout(model, starts, t, method, energy=dm.energy, **kw)
                rows.append([label, name, method, *_trained_cells(out, model, dm)])
                if label == f"{far[1]}× horizon" and method in ("dopri5", "implicit_midpoint"):
                    curves[f"{name}, {method}"] = (t, out.e_pred.mean(1))
    return rows, curves, far


def _trained_cells(out: Any, model: Any, dm: Any) -> list[str]:
    """A rollout's finite rows, median relative change of the true energy at the end
    and (HNN) the largest drift of the learned H_θ."""
    ok = out.status == Status.OK
    rel = relative_energy_error(out.e_pred[:, ok])[-1]
    drift = "—"
    if out.h_pred is not None and bool(ok.any()):
        with torch.no_grad():
            scale = model.field.hamiltonian(dm.reference_inputs(4096)).std()
        drift = f"{float(h_drift(out.h_pred[:, ok], scale).max()):.1e}"
    median = f"{float(rel.median()):.1e}" if bool(ok.any()) else "—"
    return [f"{int(ok.sum())}/{len(ok)}", median, drift]


def figure_long_runs(runs: dict, path: Path) -> None:
    plt = pyplot()

    systems = sorted({s for s, _ in runs})
    fig, axes = plt.subplots(1, len(systems), figsize=(6 * len(systems), 4), squeeze=False)
    for ax, system in zip(axes[0], systems, strict=True):
        for (s, method), r in runs.items():
            if s == system:
                ax.loglog(r["t"][1:], r["rel"].mean(1)[1:].clamp_min(1e-17), label=method)
        ax.set(
            title=f"{system}, float64, h = 0.1", xlabel="t", ylabel="|ΔH| / H (mean of 3 starts)"
        )
        ax.legend()
    save_figure(fig, path)


def figure_trained(curves: dict, path: Path, factor: int) -> None:
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(7, 4))
    for label, (t, e) in curves.items():
        ax.plot(t, e, label=label)
    ax.set(
        title=f"Trained spring models, {factor}× the training horizon",
        xlabel="t",
        ylabel="true energy (mean over held-out starts)",
    )
    ax.legend()
    save_figure(fig, path)


@dataclass
class Tables:
    """The report's tables (rows of strings) and the sizes its text names."""

    n_steps: int
    long: list[list[str]]
    n32: int
    float32: list[list[str]]
    reversibility: list[list[str]]
    hard: list[list[str]]
    trained: list[list[str]]
    far: tuple[int, int]


SYSTEMS = {"mass-spring": MassSpring, "pendulum": Pendulum}


def run(
    quick: bool = False, out: Path = Path("STABILITY.md"), beside: str = "", *, build: Any
) -> str:
    """Measure every section, draw the figures into ``<out stem>/``, write ``out`` and
    return its text. ``build``: how the trained models are made
    (:class:`hnn_pl.experiments.collect.Build`)."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    n_steps = 2_000 if quick else 1_000_000
    figures = out.with_suffix("")
    figures.mkdir(parents=True, exist_ok=True)
    systems = {name: cls() for name, cls in SYSTEMS.items()}
    long, runs = _long_run_rows(systems, n_steps)
    figure_long_runs(runs, figures / "long_runs.png")
    n32 = min(n_steps // 10, 20_000)
    f32 = _float32_rows(systems, n32)
    rev = _reversibility_rows(systems)
    hard = hard_cases(quick)
    trained, curves, far = trained_models(quick, build)
    figure_trained(curves, figures / "trained.png", far[1])
    tables = Tables(n_steps, long, n32, f32, rev, hard, trained, far)
    doc = render(tables, quick, time.perf_counter() - start, beside, figures.name)
    out.write_text(doc)
    return doc


def _long_run_rows(systems: dict[str, Any], n_steps: int) -> tuple[list[list[str]], dict]:
    """Section 1: :func:`long_run` of every system and method (dopri5 over a tenth of
    the steps); the table's rows and the runs by ``(system, method)``."""
    runs, rows = {}, []
    for sname, system in systems.items():
        for method in LONG_METHODS:
            r = long_run(system, method, n_steps // 10 if method == "dopri5" else n_steps)
            runs[(sname, method)] = r
            rows.append(
                [
                    sname,
                    method if r["ok"] else f"{method} (rows stopped)",
                    f"{r['max']:.2e}",
                    f"{r['slope']:.2e}",
                    f"{r['first']:.2e}",
                    f"{r['last']:.2e}",
                    f"{r['seconds']:.1f}",
                    f"{r['seconds'] / r['n_steps'] * 1e6:.0f}",
                ]
            )
            print(rows[-1], flush=True)
    return rows, runs


def _float32_rows(systems: dict[str, Any], n32: int) -> list[list[str]]:
    """Section 4: the maximum relative energy error over ``n32`` steps, float64 and float32."""
    rows = []
    for sname, system in systems.items():
        for method in LONG_METHODS:
            r64, r32 = (long_run(system, method, n32, dtype=d) for d in (F64, F32))
            rows.append([sname, method, f"{r64['max']:.2e}", f"{r32['max']:.2e}"])
    return rows


def _reversibility_rows(systems: dict[str, Any]) -> list[list[str]]:
    """Section 4: :func:`reversibility` of every system and method, float64 and float32."""
    return [
        [
            sname,
            method,
            f"{reversibility(system, method, F64):.1e}",
            f"{reversibility(system, method, F32):.1e}",
        ]
        for sname, system in systems.items()
        for method in LONG_METHODS
    ]


def render(t: Tables, quick: bool, seconds: float, beside: str, figures: str) -> str:
    """STABILITY.md from its tables; its figures are in the folder ``figures``."""
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    n_steps, n32, far = t.n_steps, t.n32, t.far
    doc = f"""# Numerical stability

Written by `python -m hnn_pl stress{" --quick" if quick else ""}` on {when} ({platform.machine()},
{torch.get_num_threads()} torch thread, torch {torch.__version__}) in {seconds:.0f} s{beside}.

## 1. Long runs of the true systems

{n_steps:,} steps of h = 0.1 in float64 (t ∈ [0, {n_steps / 10:,.0f}]) from 3 starts; dopri5 at
rtol = 1e-6, atol = 1e-9 over a tenth of that horizon (its drift is plain by then, and
"µs per step" is per 0.1 of time there). Relative energy error |H(y_t) − H(y_0)| / H(y_0):
its maximum, the least-squares slope of its mean over time, and its mean over the first and
last tenth of the run (equal for a bounded error, growing for a drift).

{table(LONG_HEADER, t.long)}

![relative energy error over time](long_runs.png)

## 2. Trained models far from their data

`spring_fast.yaml` and its baseline twin (trained on t ∈ [0, 3], energies of radius 0.1–1),
rolled out in float64 from the held-out starts to {far[0]}× and {far[1]}× the training horizon, and
from the same starts scaled to 2× and 5× their energy (horizon {far[0]}×). Rows that stay finite,
median relative change of the true energy at the end, and the largest drift of the learned
H_θ (HNN; max_t |H_θ(y_t) − H_θ(y_0)| / (|H_θ(y_0)| + the spread of H_θ over the training
inputs), the rollout metric `conserved_drift` of a single row).

{table(TRAINED_HEADER, t.trained)}

![true energy of trained models at {far[1]}× the training horizon](trained.png)

## 3. Hard cases

{table(["case", "status", "outcome", "max relative energy error", "seconds"], t.hard)}

## 4. float32 against float64, and reversibility

Maximum relative energy error over {n32:,} steps of h = 0.1:

{table(["system", "method", "float64", "float32"], t.float32)}

Integrate t ∈ [0, 20] (h = 0.05) and back: max |y_back − y_0|. The symmetric methods
(leapfrog, implicit midpoint) return to the start up to rounding and the iteration's
tolerance; rk4 and dopri5 only up to their error.

{table(["system", "method", "float64", "float32"], t.reversibility)}

{faults_section()}"""
    doc = doc.replace("](long_runs.png)", f"]({figures}/long_runs.png)")
    return doc.replace("](trained.png)", f"]({figures}/trained.png)")


#: case, what happens, the test that holds it (tests/test_faults.py unless named)
FAULTS = [
    (
        "a checkpoint naming a module (`_class_path`, `hnn_pl_model_class`) whose import "
        "would run code",
        "refused by comparing the names with the config's class as strings; nothing "
        "it names is imported",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[hostile-class-path], "
        "[hostile-model-class], test_checkpoint_hyperparameters_restore_only_plain_options",
    ),
    (
        "a checkpoint that is empty, truncated, random bytes, a directory or missing",
        "one line naming the file and the fault, before any data; never torch's "
        "`weights_only=False` advice",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[zero-byte-checkpoint], "
        "[truncated-checkpoint], [random-bytes-checkpoint], [checkpoint-is-a-directory], "
        "[missing-checkpoint], [missing-resume-checkpoint]",
    ),
    (
        "a checkpoint holding pickled objects",
        "refused, naming the object; never unpickled",
        "test_bad_input.py::test_a_checkpoint_that_is_more_than_weights_is_not_unpickled",
    ),
    (
        "a start that is inf or NaN, or a row whose state becomes non-finite",
        "`Status.DIVERGED` for that row in `odeint(return_status=True)` (all five "
        "methods) and `hnn_pl.rollout`; the other rows are unchanged",
        "test_a_non_finite_start_is_not_ok, test_a_row_that_overflows_is_not_ok, "
        "test_rollout_of_a_model_from_an_infinite_start_is_not_ok",
    ),
    (
        "predict `starts:` missing, not a tensor, of the wrong width, or not finite",
        "one line before data or a version directory is made",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[starts-missing], "
        "[starts-not-a-tensor], [starts-wrong-width], [starts-not-finite]",
    ),
    (
        "a user system whose H is not `(B,)`, is NaN on sampled starts, or whose sampler "
        "is not float64 `(n, 2·dof)`",
        "one line naming the class and the fault, checked on the data's own starts "
        "when the data module is built",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[system-h-shape], "
        "[system-h-nan], [system-sampler-width], [system-sampler-dtype]",
    ),
    (
        "a user system's `hamiltonian` edited in place",
        "a new cache key (it covers the source file of a system outside the package)",
        "test_the_cache_key_covers_a_user_system_s_source",
    ),
    (
        "a full disk under the cache or the checkpoints",
        "one line `no space left on <directory>`; the partial file removed; a good "
        "`last.ckpt` kept (checkpoints are written to a temporary file and renamed)",
        "test_a_full_disk_never_replaces_a_good_checkpoint, "
        "test_a_full_disk_leaves_no_partial_cache, "
        "test_fit_on_a_full_file_system_says_so_in_one_line (a 64 KB tmpfs where allowed)",
    ),
    (
        "kill -9 of `reproduce`",
        "its worker dies with it (PR_SET_PDEATHSIG, and a thread watching the parent), "
        "so does the resource tracker",
        "test_killing_the_pool_s_parent_leaves_no_worker_or_resource_tracker, "
        "test_killing_reproduce_leaves_no_worker_or_resource_tracker",
    ),
    (
        "Ctrl-C of `reproduce`, or a worker killed",
        "one line: how many runs finished and where they are kept; exit 130 / 2",
        "test_ctrl_c_and_a_dead_worker_end_in_one_line",
    ),
    (
        "`reproduce --out` naming a directory",
        "one line before any data is made",
        "test_every_cli_failure_is_one_line_and_leaves_nothing[reproduce-out-is-a-directory]",
    ),
    (
        "`max_steps: -5`, `--threads abc`, an empty config",
        "one line each",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[max-steps-negative], "
        "[threads-abc], [empty-config]",
    ),
    (
        "a misspelled option, class path or config name",
        "one line with the closest valid names (`did you mean hidden_dim?`), no usage dump",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[option-typo], "
        "[trainer-option-typo], [class-path-typo], [short-class-typo], [config-name-typo]",
    ),
    (
        "`n_trajectories: 1000000000`",
        "refused in one line from an estimate of its memory against the machine's",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[data-beyond-memory], "
        "test_a_data_set_beyond_the_machine_s_memory_is_refused_before_sampling",
    ),
    (
        "any other bad option value or config file",
        "one line, exit 2, nothing written",
        "test_bad_input.py",
    ),
    (
        "a recording cell that is not a decimal number (`abc`, empty, `1_5`, `0x10`), a text "
        "or non-integer id (`1e300`, `1.5`, beyond int64, uint64 ≥ 2⁶³)",
        "one line naming the file, the line or row and the column; ids read as integers "
        "exactly, never through float64",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[recording-abc], [recording-empty-cell], [recording-underscore], [recording-hex], "
        "[recording-string-id], [recording-id-1e300], [recording-id-fraction], "
        "[recording-id-beyond-int64], [recording-uint64-ids]",
    ),
    (
        "a gzip file named `.csv`, a pickle named `.npz`, garbage or a numpy file named `.pt`",
        "one line naming the file and what it is; nothing is unpickled and no numpy or torch "
        "text or unsafe-load advice reaches the user",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[recording-gzip-csv], [recording-pickle-npz], [recording-garbage-pt], "
        "[recording-numpy-pt]",
    ),
    (
        "a recording whose time steps or values float32 cannot hold (Unix-epoch times are "
        "shifted to start at 0 first), a trajectory shorter than the window",
        "one line naming the row and `data.init_args.dtype: float64`, or the trajectory and "
        "the window that fits",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[recording-float32-spacing], [recording-float32-overflow], "
        "[recording-short-trajectory]",
    ),
    (
        "resuming on another recording or another number of samples, or with options other "
        "than the checkpoint's",
        "one line naming both data sources (a fingerprint of the training observations is in "
        "the checkpoint; `reinit_states: true` starts the states anew) or the option and the "
        "checkpoint's value",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[resume-on-another-recording], [resume-on-more-samples], [resume-with-another-lr], "
        "[resume-with-another-objective], [test-with-another-objective]",
    ),
    (
        "a checkpoint with non-finite weights, or of another system than the config's",
        "refused by `test`, `predict` and `bump` in one line naming the tensor or both systems",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[test-nan-checkpoint], [predict-nan-checkpoint], [bump-nan-checkpoint], "
        "[test-another-system], [bump-another-system]",
    ),
    (
        "trajectory-objective options with `objective: derivative`, `state_weight: .inf`",
        "one line naming the options that would do nothing, or the value",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[derivative-learned-states], [derivative-continuity-weight], [derivative-substeps], "
        "[derivative-traj-method], [derivative-state-weight], [derivative-keep-fraction], "
        "[state-weight-inf]",
    ),
    (
        "a command's number out of range: `bump --starts 0`, `-1`, `1_5`, `--n_points 0`, "
        "`--t_end -1` or `inf`, `--delta nan`; `reproduce --seeds 0`, `--workers -1`; "
        "`--threads 0`; a seed beyond numpy's range",
        "one line naming the option and the value it needs, at parse time",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[bump-starts-zero], [bump-starts-negative], [bump-starts-underscore], "
        "[bump-n-points-zero], [bump-n-points-one], [bump-t-end-negative], [bump-t-end-zero], "
        "[bump-t-end-inf], [bump-delta-nan], [bump-delta-inf], [bump-delta-overflow], "
        "[bump-starts-beyond-the-data], [reproduce-seeds-zero], [reproduce-seeds-fraction], "
        "[reproduce-first-seed-negative], [reproduce-workers-negative], "
        "[reproduce-max-steps-zero], [threads-zero], [threads-fraction], [seed-beyond-numpy]",
    ),
    (
        "`bump --out` naming a file; trainer settings Lightning does not check "
        "(`check_val_every_n_epoch: 0`, `val_check_interval: 0`, `accumulate_grad_batches: "
        "0`, `num_sanity_val_steps: -2`)",
        "one line naming the option, before anything runs",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[bump-out-is-a-file], [bump-out-below-a-file], [trainer-check-val-zero], "
        "[trainer-val-check-interval-zero], [trainer-accumulate-zero], "
        "[trainer-sanity-steps-negative]",
    ),
    (
        "a refusal after the run started: a window longer than every trajectory, an objective"
        " that does not fit the data, a test refused at its first batch",
        "one line, the only line on stderr, and the run's own files (config, hparams, events)"
        " taken back: nothing new on disk",
        "test_every_cli_failure_is_one_line_and_leaves_nothing"
        "[window-longer-than-every-trajectory], [objective-data-mismatch], "
        "[test-refused-at-its-first-batch]",
    ),
]


def faults_section() -> str:
    """The "Faults and bad input" section of STABILITY.md, from :data:`FAULTS`."""
    rows = [[case, what, f"`{held}`"] for case, what, held in FAULTS]
    return (
        "## 5. Faults and bad input\n\n"
        "Every failure of a command ends with one line on stderr "
        "(`python -m hnn_pl: error: …`) and exit status 2, with no traceback "
        "(`HNN_PL_TRACEBACK=1` shows it) and nothing new on disk unless it is a "
        "complete, valid file. Tests are in `tests/test_faults.py` unless named.\n\n"
        + table(["case", "what happens", "the test that holds it"], rows)
        + "\n"
    )


def parse(parser: ArgumentParser, argv: list[str] | None = None) -> Namespace:
    """The options of ``stress`` read from ``argv``; ``out`` defaults by ``quick``."""
    parser.add_argument(
        "--quick", action="store_true", help="2,000 instead of 10⁶ steps; a short training"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="report (default STABILITY.md; quick: STABILITY-quick.md)",
    )
    parser.add_argument("--beside", default="", help="what else ran, for the report's header")
    args = parser.parse_args(argv)
    args.out = args.out or Path("STABILITY-quick.md" if args.quick else "STABILITY.md")
    return args


def main(args: Namespace, build: Any) -> int:
    """Write the report :func:`parse` asked for (``build``: see :func:`run`)."""
    run(args.quick, args.out, f", beside {args.beside}" if args.beside else "", build=build)
    print(f"wrote {args.out} and its figures in {args.out.with_suffix('')}/")
    return 0
