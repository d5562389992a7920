"""Benchmarks: run time against error of the integrators, training steps, data
generation and start-up, written as a Markdown report.

``python -m hnn_pl.bench [--quick] [--out BENCHMARKS.md] [--threads N] [--only NAME ...]``

Sections (``--only`` takes their names):

- ``integrators``: every method of :func:`hnn_pl.odeint` and scipy's ``solve_ivp``
  over a sweep of step sizes and tolerances, on the true pendulum field and on an
  HNN field, 25 and 1000 starts, float32 and float64: wall time, field evaluations,
  error against a tight float64 reference, energy drift, and the fastest setting
  for a few error targets.
- ``training``: one optimiser step of the HNN (closed-form input gradient and
  autograd double backward) and of the baseline at the paper's batch shapes, 1 and
  ``N`` threads; the same step inside ``Trainer.fit``; ``torch.compile``.
- ``data``: :class:`~hnn_pl.data.SimulatedData` generation and cache-hit loading.
- ``startup``: ``python -m hnn_pl --help`` and imports, in fresh interpreters.

Timings are medians of repeated runs after a warm-up run; every table states its
repeat count. The benchmarks assert nothing about time: compare numbers within one
report only, as other processes on the machine move them.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import datetime as _dt
import importlib.metadata
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.integrate import odeint, scipy_odeint
from hnn_pl.nets import MLP, DirectField, HamiltonianField
from hnn_pl.systems import MassSpring, Pendulum, ThreeBody, TwoBody

__all__ = [
    "BENCHMARKS",
    "CountingField",
    "Section",
    "bench_data",
    "bench_integrators",
    "bench_startup",
    "bench_training",
    "machine_info",
    "main",
    "time_call",
    "trained_like_hnn",
]

F32, F64 = torch.float32, torch.float64
_DTYPE_NAME = {F32: "float32", F64: "float64"}
T_END, N_TIMES = 20.0, 201
ERROR_TARGETS = (1e-3, 1e-6, 1e-9)
REFERENCE_TOL = 1e-13


# ---------------------------------------------------------------------------------
# timing and report helpers


@dataclass
class Section:
    """One section of the report.

    Attributes:
        name: the ``--only`` name.
        title: the Markdown heading.
        body: Markdown text (tables and notes) under the heading.
        facts: measured numbers the report's prose summary is written from.
        seconds: wall time the section took.
        load: the 1-minute load average before and after the section.
    """

    name: str
    title: str
    body: str
    facts: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    load: tuple[float, float] = (math.nan, math.nan)


def time_call(
    fn: Callable[[], Any], min_time: float = 1.0, max_repeats: int = 5, once_above: float = 1.0
) -> tuple[list[float], Any]:
    """Time ``fn()``: a warm-up call, then repeated timed calls.

    The warm-up call's result is returned (for error and evaluation counts). If the
    warm-up took at least ``once_above`` seconds it is the only timing (first-call
    overheads are milliseconds); otherwise ``fn`` is timed ``n`` more times, with
    ``n = clamp(min_time / warm-up time, 2, max_repeats)``.

    Returns:
        the list of timings in seconds (report their median) and ``fn()``'s result.
    """
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    if first >= once_above:
        return [first], out
    n = max(2, min(max_repeats, int(min_time / max(first, 1e-9))))
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times, out


@contextlib.contextmanager
def _threads(n: int) -> Iterator[None]:
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _table(header: list[str], rows: list[list[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _ms(seconds: float) -> str:
    """Milliseconds with 3-4 significant digits (a plain number, for parsing)."""
    ms = 1e3 * seconds
    return f"{ms:.3g}" if ms < 100 else f"{ms:.0f}"


def _sci(x: float) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.2e}"


def _load1() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return math.nan


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _version(pkg: str) -> str:
    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def machine_info(threads: int) -> dict[str, str]:
    """CPU model, cores, library versions, torch threads, date and load average."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return {
        "CPU": _cpu_model(),
        "cores": f"{os.cpu_count()} logical ({usable} usable by this process)",
        "torch threads": str(threads),
        "torch": torch.__version__,
        "lightning / scipy / numpy": " / ".join(
            _version(p) for p in ("lightning", "scipy", "numpy")
        ),
        "python": platform.python_version(),
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "load average (1/5/15 min) at start": " / ".join(f"{x:.2f}" for x in os.getloadavg()),
    }


# ---------------------------------------------------------------------------------
# 1. integrators: run time against error


class CountingField:
    """Wraps a field ``f(t, y)`` and counts its calls and the rows it evaluated.

    ``dopri5`` evaluates only unfinished rows, so ``rows / batch`` is the mean number
    of evaluations per trajectory, while ``calls`` is what a fixed-overhead field pays.
    """

    def __init__(self, func: Callable[[Tensor, Tensor], Tensor]) -> None:
        self.func = func
        self.calls = 0
        self.rows = 0

    def reset(self) -> None:
        self.calls = self.rows = 0

    def __call__(self, t: Tensor, y: Tensor) -> Tensor:
        self.calls += 1
        self.rows += y.shape[0]
        return self.func(t, y)


def trained_like_hnn(steps: int = 400, seed: int = 0) -> tuple[HamiltonianField, float]:
    """``HamiltonianField(MLP(2, 1))`` (seed ``seed``) fitted to the pendulum's ``J∇H``.

    An untrained orthogonal-init MLP's symplectic gradient is nearly constant over the
    pendulum's states (dopri5 needs 26 evaluations for t ∈ [0, 20]), so the field is
    first fitted for ``steps`` full-batch Adam steps (lr 1e-3) to the pendulum
    ``H = 3(1 − cos q) + p²`` on 512 states uniform in [−2.6, 2.6]²: its orbits then
    have the time scales, and the integrators the work, of a trained HNN.

    Returns:
        the float32 field (parameters frozen) and its final training MSE.
    """
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        hnn = HamiltonianField(MLP(2, 1))
    g = torch.Generator().manual_seed(seed)
    x = (torch.rand(512, 2, generator=g) * 2 - 1) * 2.6
    dx = Pendulum().vector_field(None, x)
    opt = torch.optim.Adam(hnn.parameters(), lr=1e-3)
    for _ in range(steps):
        loss = nn.functional.mse_loss(hnn(x), dx)
        opt.zero_grad()
        loss.backward()
        opt.step()
    hnn.requires_grad_(False)
    return hnn, float(loss.detach())


def _odeint_runner(method: str, **kwargs) -> Callable:
    def run(func, y0: Tensor, t: Tensor) -> Tensor:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return odeint(func, y0, t, method=method, **kwargs)

    return run


def _scipy_runner(tol: float, per_trajectory: bool) -> Callable:
    def solve(func, y0: Tensor, t: Tensor) -> Tensor:
        return scipy_odeint(func, y0, t, "RK45", y0.dtype, rtol=tol, atol=tol)

    def run(func, y0: Tensor, t: Tensor) -> Tensor:
        if not per_trajectory:
            return solve(func, y0, t)
        return torch.cat([solve(func, y0[b : b + 1], t) for b in range(y0.shape[0])], 1)

    return run


_METHOD_ORDER = [
    "rk4",
    "leapfrog",
    "implicit_midpoint",
    "dopri5",
    "scipy RK45, batch",
    "scipy RK45, per trajectory",
]


@dataclass
class _Setting:
    method: str
    label: str
    dtype: torch.dtype
    value: float
    run: Callable


_FIXED = ("rk4", "leapfrog", "implicit_midpoint")


def _sweep(spec: dict[torch.dtype, dict[str, tuple[float, ...]]]) -> list[_Setting]:
    """Settings from ``{dtype: {method: values}}``; methods: the fixed-step ones (step
    sizes), ``dopri5``, ``scipy`` (flattened batch), ``scipy_per_traj`` (tolerances)."""
    out = []
    for dtype, methods in spec.items():
        for method in _FIXED:
            for h in methods.get(method, ()):
                run = _odeint_runner(method, step_size=h)
                out.append(_Setting(method, f"h={h:g}", dtype, h, run))
        for tol in methods.get("dopri5", ()):
            run = _odeint_runner("dopri5", rtol=tol, atol=tol)
            out.append(_Setting("dopri5", f"tol={tol:.0e}", dtype, tol, run))
        for key, name, per in (
            ("scipy", "scipy RK45, batch", False),
            ("scipy_per_traj", "scipy RK45, per trajectory", True),
        ):
            for tol in methods.get(key, ()):
                out.append(_Setting(name, f"tol={tol:.0e}", dtype, tol, _scipy_runner(tol, per)))
    return out


def _sweeps(quick: bool) -> dict[tuple[str, int], list[_Setting]]:
    """The settings of every (field, starts) case."""
    if quick:
        spec = {"rk4": (0.1, 0.05, 0.02), "leapfrog": (0.1, 0.05), "implicit_midpoint": (0.1, 0.05)}
        spec |= {"dopri5": (1e-4, 1e-6, 1e-8), "scipy": (1e-4, 1e-6, 1e-8)}
        return {("pendulum", 25): _sweep({F64: {**spec, "scipy_per_traj": (1e-4,)}})}
    hs = dict.fromkeys(_FIXED, (0.1, 0.05, 0.02, 0.01))
    tol32, tol64 = (1e-4, 1e-5, 1e-6, 1e-7), tuple(10.0**-k for k in range(4, 11))
    f32 = {**hs, "dopri5": tol32, "scipy": tol32}
    # dopri5 float64 also at 1e-11, 1e-12: the global error at t = 20 is ~100× the tolerance
    f64 = {**hs, "dopri5": (*tol64, 1e-11, 1e-12), "scipy": tol64}
    # one HNN evaluation of 1000 states costs milliseconds: a coarser sweep there
    big32 = {"rk4": (0.1, 0.05, 0.02), "leapfrog": (0.1, 0.05), "implicit_midpoint": (0.1, 0.05)}
    big32 |= {"dopri5": (1e-4, 1e-6), "scipy": (1e-4, 1e-6)}
    big64 = {"rk4": (0.1,), "dopri5": (1e-6,)}
    # extra float64 settings that can reach the 1e-9 error target
    rk4_fine = (*hs["rk4"], 0.005, 0.0025)
    pend64 = {**f64, "rk4": rk4_fine, "dopri5": (*f64["dopri5"], 1e-13)}
    return {
        ("pendulum", 25): _sweep({F32: f32, F64: {**pend64, "scipy_per_traj": (1e-4, 1e-6, 1e-8)}}),
        ("pendulum", 1000): _sweep({F32: f32, F64: pend64}),
        ("hnn", 25): _sweep(
            {F32: f32, F64: {**f64, "rk4": (*hs["rk4"], 0.0025), "scipy_per_traj": (1e-4,)}}
        ),
        ("hnn", 1000): _sweep({F32: big32, F64: big64}),
    }


def _reference(func, y0: Tensor, t: Tensor, tol: float = REFERENCE_TOL) -> Tensor:
    """Float64 ``(T, B, D)`` from scipy's DOP853 at ``rtol = atol = tol`` (flattened batch)."""
    return scipy_odeint(func, y0, t, "DOP853", rtol=tol, atol=tol)


@dataclass
class _Row:
    field: str
    batch: int
    method: str
    setting: str
    dtype: str
    value: float
    times: list[float] = field(default_factory=list)
    calls: int = 0
    evals_per_traj: float = math.nan
    error: float = math.nan
    drift: float = math.nan
    failure: str = ""

    @property
    def time(self) -> float:
        return statistics.median(self.times) if self.times else math.nan


def _integrator_case(
    field_name: str,
    batch: int,
    settings: list[_Setting],
    fields: dict[torch.dtype, Callable],
    y0_all: Tensor,
    t64: Tensor,
    ref: Tensor,
    eval_rows: int,
    energy: Callable[[Tensor], Tensor],
    scale: float | None,
    timing: dict,
    log: Callable[[str], None],
) -> list[_Row]:
    rows = []
    y0 = y0_all[:batch]
    e0 = energy(y0[:eval_rows])
    for s in settings:
        row = _Row(field_name, batch, s.method, s.label, _DTYPE_NAME[s.dtype], s.value)
        counter = CountingField(fields[s.dtype])
        y0_d, t_d = y0.to(s.dtype), t64.to(s.dtype)
        try:
            row.times, y = time_call(
                lambda s=s, counter=counter, y0_d=y0_d, t_d=t_d: s.run(counter, y0_d, t_d),
                **timing,
            )
        except (RuntimeError, ValueError) as err:
            row.failure = str(err).splitlines()[0][:120]
            rows.append(row)
            log(f"  {field_name} B={batch} {s.method} {s.label} {row.dtype}: FAILED {err}")
            continue
        runs = 1 + (len(row.times) if len(row.times) > 1 else 0)
        row.calls = counter.calls // runs
        row.evals_per_traj = counter.rows / runs / batch
        y = y[:, :eval_rows].double()
        row.error = float((y - ref[:, :eval_rows]).abs().max())
        e = energy(y)
        row.drift = float(((e - e0).abs() / (e0.abs() if scale is None else scale)).max())
        if not math.isfinite(row.error):
            row.failure = "non-finite states"
        rows.append(row)
        log(
            f"  {field_name} B={batch} {s.method} {s.label} {row.dtype}: "
            f"{row.time:.3f}s x{len(row.times)} err {row.error:.2e}"
        )
    return rows


def _pareto(rows: list[_Row], target: float) -> _Row | None:
    ok = [r for r in rows if not r.failure and r.error <= target]
    return min(ok, key=lambda r: r.time) if ok else None


def bench_integrators(quick: bool = False, log: Callable[[str], None] = print) -> Section:
    """Section 1: run time against error of every integrator setting (see module doc)."""
    timing = (
        {"min_time": 0.2, "max_repeats": 3, "once_above": 0.5}
        if quick
        else {"min_time": 0.75, "max_repeats": 5, "once_above": 0.75}
    )
    threads = torch.get_num_threads()
    pend = Pendulum()
    t64 = torch.linspace(0.0, T_END, N_TIMES, dtype=F64)
    y0_all = pend.sample_initial(25 if quick else 1000, torch.Generator().manual_seed(0))
    sweeps = _sweeps(quick)
    notes: list[str] = []

    def pend_energy(y: Tensor) -> Tensor:
        return pend.hamiltonian(y)

    cases: dict[str, dict[str, Any]] = {
        "pendulum": {
            "fields": {F32: pend.vector_field, F64: pend.vector_field},
            "energy": pend_energy,
            "title": "true pendulum field, H = 3(1 − cos q) + p²",
        }
    }
    if any(name == "hnn" for name, _ in sweeps):
        t0 = time.perf_counter()
        hnn32, fit_loss = trained_like_hnn()
        hnn64 = copy.deepcopy(hnn32).double()
        scale = float(hnn64.hamiltonian(y0_all).std())

        def hnn_energy(y: Tensor, scale=scale) -> Tensor:
            with torch.no_grad():
                return hnn64.hamiltonian(y.reshape(-1, y.shape[-1])).reshape(y.shape[:-1])

        cases["hnn"] = {
            "fields": {F32: hnn32.vector_field, F64: hnn64.vector_field},
            "energy": hnn_energy,
            "scale": scale,
            "title": "HNN field J∇H_θ, H_θ = MLP(2 → 200 → 200 → 1), closed-form ∇H_θ",
        }
        notes.append(
            f"HNN field: `HamiltonianField(MLP(2, 1))`, seed 0, fitted for 400 Adam steps to "
            f"the pendulum's J∇H on 512 states (final MSE {fit_loss:.1e}, "
            f"{time.perf_counter() - t0:.1f} s, not part of any timing), so that its orbits "
            "have a trained HNN's time scales. Its energy drift is "
            "max |H_θ(y(t)) − H_θ(y(0))| divided by the standard deviation of H_θ over the "
            f"1000 starts ({scale:.3g}), since H_θ has an arbitrary offset."
        )

    rows: list[_Row] = []
    refs: dict[str, Tensor] = {}
    for (name, batch), settings in sweeps.items():
        case = cases[name]
        eval_rows = batch if name == "pendulum" else min(batch, 25)
        if name not in refs:
            n_ref = max(b for (n, b) in sweeps if n == name) if name == "pendulum" else 25
            t0 = time.perf_counter()
            refs[name] = _reference(case["fields"][F64], y0_all[:n_ref], t64)
            log(f"reference {name} ({n_ref} starts): {time.perf_counter() - t0:.1f}s")
        rows += _integrator_case(
            name,
            batch,
            settings,
            case["fields"],
            y0_all,
            t64,
            refs[name],
            eval_rows,
            case["energy"],
            case.get("scale"),
            timing,
            log,
        )

    body = [_integrator_intro(threads, quick, timing)]
    body += [f"- {n}" for n in notes]
    if not quick:
        body.append(f"- {_reference_check(pend, y0_all, t64, refs['pendulum'], log)}")
    body.append("")
    for (name, batch), _ in sweeps.items():
        case_rows = [r for r in rows if r.field == name and r.batch == batch]
        body.append(f"### {cases[name]['title']}: {batch} starts\n")
        if name == "hnn" and batch > 25:
            body.append(
                "Error and energy drift on the first 25 starts (the 25-start set); a "
                "float64 reference for all 1000 would cost more than this sweep. A coarser "
                "sweep: one HNN evaluation of 1000 states costs milliseconds.\n"
            )
        body.append(_integrator_table(case_rows))
        body.append("")
    body.append("### Fastest setting per error target\n")
    body.append(
        "The fastest row of the tables above whose max state error is at most the "
        "target (float32 and float64 rows compete).\n"
    )
    body.append(_pareto_table(rows, sweeps))
    body += ["", "### Comparisons at equal tolerance\n"]
    body += [f"- {line}" for line in _integrator_comparisons(rows, sweeps)]
    facts: dict[str, Any] = {
        "pareto": {
            (name, batch, target): _pareto(
                [r for r in rows if r.field == name and r.batch == batch], target
            )
            for name, batch in sweeps
            for target in ERROR_TARGETS
        },
        "cases": list(sweeps),
        "per_traj": tuple(
            _find(rows, "pendulum", 25, m, "tol=1e-06")
            for m in ("scipy RK45, per trajectory", "scipy RK45, batch", "dopri5")
        ),
    }
    if not quick:
        facts["threads"], text = _rollout_threads(cases, y0_all, t64, log)
        body += ["", "### Threads for rollouts\n", text]
    return Section("integrators", "1. Integrators: run time against error", "\n".join(body), facts)


def _integrator_intro(threads: int, quick: bool, timing: dict) -> str:
    return "\n".join(
        [
            f"t ∈ [0, {T_END:g}], outputs at {N_TIMES} equally spaced times; starts from "
            "`Pendulum().sample_initial` (seed 0; radius U[1.3, 2.3], some close to the "
            "separatrix), the 25-start set being the first 25 of the 1000. "
            f"{threads} torch thread(s).",
            "",
            "- **time (ms)**: median of `n` timed runs after one warm-up run (runs of "
            f"{timing['once_above']:g} s or more: `n = 1`, the warm-up run itself); "
            "includes everything from the "
            "call to the returned `(T, B, D)` tensor, under `torch.no_grad`.",
            "- **calls**: calls of the field per solve; **evals/traj**: rows evaluated / "
            "starts (dopri5 evaluates only unfinished trajectories; scipy's per-trajectory "
            "solve calls the field once per row).",
            f"- **max error**: max over times, starts and coordinates of |y − y_ref|, with "
            f"y_ref scipy DOP853 at rtol = atol = {REFERENCE_TOL:g} in float64 on the same "
            "field. **energy drift**: max |E(y(t)) − E(y(0))| / |E(y(0))| at the output "
            "times (pendulum), see below for the HNN.",
            "- fixed-step methods cut each 0.1-long output interval into equal steps of "
            "`h`; `implicit_midpoint` iterates to odeint's default rtol 1e-7 / atol 1e-9. "
            "`leapfrog` is symplectic and 2nd order only for a separable H; the HNN's H_θ "
            "is not (odeint warns; the warning is silenced here). dopri5 has per-trajectory "
            "step control with rtol = atol = tol; scipy RK45 gets rtol = atol = tol too, "
            "on the flattened batch (`scipy_fun`, one step size for all trajectories) or "
            "one `solve_ivp` call per trajectory as the reference code does. float32 rows "
            "of scipy evaluate the field in float32 while scipy integrates in float64; "
            "float32 tolerances stop at 1e-7 (dopri5 cannot resolve tighter). To reach the "
            "1e-9 error target, float64 dopri5 continues to 1e-12 (pendulum: 1e-13) and "
            "float64 rk4 to h = 0.0025 (pendulum also 0.005).",
            "- rows are sorted by time within each method.",
        ]
        + (["- `--quick`: pendulum, 25 starts, float64, a few settings only."] if quick else [])
    )


_INTEGRATOR_HEADER = [
    "method",
    "setting",
    "dtype",
    "time (ms)",
    "n",
    "calls",
    "evals/traj",
    "max error",
    "energy drift",
]


def _integrator_table(rows: list[_Row]) -> str:
    out = []
    for method in _METHOD_ORDER:
        mrows = [r for r in rows if r.method == method]
        for r in sorted(mrows, key=lambda r: (bool(r.failure), r.time)):
            if r.failure:
                out.append([r.method, r.setting, r.dtype, "failed", "", "", "", r.failure, ""])
                continue
            out.append(
                [
                    r.method,
                    r.setting,
                    r.dtype,
                    _ms(r.time),
                    len(r.times),
                    r.calls,
                    f"{r.evals_per_traj:.0f}",
                    _sci(r.error),
                    _sci(r.drift),
                ]
            )
    return _table(_INTEGRATOR_HEADER, out)


def _pareto_table(rows: list[_Row], sweeps) -> str:
    out = []
    for name, batch in sweeps:
        case_rows = [r for r in rows if r.field == name and r.batch == batch]
        for target in ERROR_TARGETS:
            best = _pareto(case_rows, target)
            if best is None:
                ok = [r for r in case_rows if not r.failure]
                low = min(ok, key=lambda r: r.error) if ok else None
                what = "none in the sweep" + (f" (smallest error {_sci(low.error)})" if low else "")
                out.append([name, batch, f"{target:.0e}", what, "", ""])
            else:
                setting = f"{best.method} {best.setting} {best.dtype}"
                out.append(
                    [name, batch, f"{target:.0e}", setting, _ms(best.time), _sci(best.error)]
                )
    return _table(["field", "starts", "error ≤", "fastest setting", "time (ms)", "error"], out)


def _find(rows, name, batch, method, setting, dtype="float64") -> _Row | None:
    for r in rows:
        if (r.field, r.batch, r.method, r.setting, r.dtype) == (
            name,
            batch,
            method,
            setting,
            dtype,
        ):
            return None if r.failure else r
    return None


def _integrator_comparisons(rows: list[_Row], sweeps) -> list[str]:
    lines = []
    for name in ("pendulum", "hnn"):
        for tol in ("tol=1e-04", "tol=1e-06"):
            per = _find(rows, name, 25, "scipy RK45, per trajectory", tol)
            flat = _find(rows, name, 25, "scipy RK45, batch", tol)
            dop = _find(rows, name, 25, "dopri5", tol)
            if per and flat and dop:
                lines.append(
                    f"{name}, 25 starts, {tol}, float64: one `solve_ivp` per trajectory "
                    f"{_ms(per.time)} ms (error {_sci(per.error)}), one call on the flattened "
                    f"batch {_ms(flat.time)} ms (error {_sci(flat.error)}), torch dopri5 "
                    f"{_ms(dop.time)} ms (error {_sci(dop.error)})."
                )
    for name, batch in sweeps:
        a = _find(rows, name, batch, "dopri5", "tol=1e-08")
        b = _find(rows, name, batch, "scipy RK45, batch", "tol=1e-08")
        if a and b:
            lines.append(
                f"{name}, {batch} starts, tol 1e-8, float64: dopri5 (per-trajectory control) "
                f"{_ms(a.time)} ms, {a.calls} calls, error {_sci(a.error)}; scipy RK45 on the "
                f"flattened batch {_ms(b.time)} ms, {b.calls} calls, error {_sci(b.error)}."
            )
    return lines


def _reference_check(pend, y0_all, t64, ref, log) -> str:
    """How far the reference is from an independent one (our dopri5 at the same tolerance)."""
    t0 = time.perf_counter()
    with torch.no_grad():
        alt = odeint(
            pend.vector_field, y0_all[:25], t64, "dopri5", rtol=REFERENCE_TOL, atol=REFERENCE_TOL
        )
    own = _reference(pend.vector_field, y0_all[:25], t64)
    d_alt = float((alt - ref[:, :25]).abs().max())
    d_own = float((own - ref[:, :25]).abs().max())
    log(f"reference check: {time.perf_counter() - t0:.1f}s")
    return (
        "Reference check (pendulum, first 25 starts): the DOP853 reference differs by "
        f"{d_alt:.1e} from torch dopri5 at rtol = atol = {REFERENCE_TOL:g} (per-trajectory "
        f"control), and by {d_own:.1e} from DOP853 solved on those 25 starts alone instead "
        f"of with all 1000: errors of order {max(d_alt, d_own):.0e} or below are at the "
        "reference's resolution."
    )


def _rollout_threads(cases, y0_all, t64, log) -> tuple[dict, str]:
    """rk4 h = 0.1 float32, the HNN field, 25 and 1000 starts, 1 and 2 threads."""
    name = "hnn" if "hnn" in cases else "pendulum"
    func = cases[name]["fields"][F32]
    run = _odeint_runner("rk4", step_size=0.1)
    out, results = [], {}
    t32 = t64.float()
    for batch in (25, 1000):
        y0 = y0_all[:batch].float()
        for n in (1, 2):
            with _threads(n):
                times, _ = time_call(lambda y0=y0: run(func, y0, t32), 1.0, 3, 1.0)
            results[batch, n] = times
            out.append([batch, n, _ms(statistics.median(times)), len(times)])
            log(f"  threads {batch} x{n}: {statistics.median(times):.3f}s")
    text = f"rk4, h = 0.1 (800 field calls), float32, {name} field, t ∈ [0, 20].\n\n" + _table(
        ["starts", "threads", "time (ms)", "n"], out
    )
    return {k: statistics.median(v) for k, v in results.items()}, text


# ---------------------------------------------------------------------------------
# 2. training step

TRAIN_SHAPES = ((750, 2, "spring, full batch"), (200, 8, "two-body batch"), (600, 12, "three-body"))


def _make_field(kind: str, dim: int) -> nn.Module:
    with torch.random.fork_rng():
        torch.manual_seed(0)
        if kind == "baseline":
            return DirectField(MLP(dim, dim))
        return HamiltonianField(MLP(dim, 1), closed_form=(kind == "hnn closed-form"))


def _step_times(
    loss_fn: Callable[[], Tensor], params, n_steps: int, warmup: int = 5
) -> tuple[list[float], float]:
    """Per-step wall times of ``zero_grad, loss, backward, Adam step``; and the first step."""
    opt = torch.optim.Adam(params, lr=1e-3)

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        loss_fn().backward()
        opt.step()

    t0 = time.perf_counter()
    step()
    first = time.perf_counter() - t0
    for _ in range(warmup - 1):
        step()
    times = []
    for _ in range(n_steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return times, first


def _batch(n: int, d: int) -> tuple[Tensor, Tensor]:
    g = torch.Generator().manual_seed(0)
    return torch.randn(n, d, generator=g), torch.randn(n, d, generator=g)


def bench_training(
    quick: bool = False, threads: int = 2, log: Callable[[str], None] = print
) -> Section:
    """Section 2: HNN (closed form, autograd) and baseline training steps, Lightning, compile."""
    shapes = TRAIN_SHAPES[:1] if quick else TRAIN_SHAPES
    thread_list = [1] if quick else sorted({1, threads})
    n_steps = 10 if quick else 40
    kinds = ("hnn closed-form", "hnn autograd", "baseline")
    res: dict[tuple, float] = {}
    rows = []
    for n, d, what in shapes:
        x, dx = _batch(n, d)
        for th in thread_list:
            with _threads(th):
                for kind in kinds:
                    fld = _make_field(kind, d)

                    def loss_fn(fld=fld, x=x, dx=dx) -> Tensor:
                        return nn.functional.mse_loss(fld.vector_field(None, x), dx)

                    times, _ = _step_times(loss_fn, fld.parameters(), n_steps)
                    res[n, d, th, kind] = statistics.median(times)
                    log(f"  train {n}x{d} {th}t {kind}: {res[n, d, th, kind] * 1e3:.2f} ms")
            cf, ag, bl = (res[n, d, th, k] for k in kinds)
            rows.append(
                [
                    f"{n}×{d} ({what})",
                    th,
                    _ms(cf),
                    _ms(ag),
                    _ms(bl),
                    f"{ag / cf:.2f}",
                    f"{cf / bl:.2f}",
                ]
            )
    body = [
        "One optimiser step = `zero_grad`, loss = MSE(field(x), dy/dt), `backward`, Adam "
        "(lr 1e-3) on float32 random inputs of the paper's batch shapes, "
        "`MLP(d → 200 → 200 → out)`. HNN closed-form: `HamiltonianField` with "
        "`MLP.value_and_input_grad` (one ordinary backward); autograd: "
        "`closed_form=False` (`autograd.grad(create_graph=True)`, double backward); "
        f"baseline: the MLP outputs dy/dt. Median of {n_steps} timed steps after 5 warm-up "
        "steps.\n",
        _table(
            [
                "batch × dim",
                "threads",
                "HNN closed-form (ms)",
                "HNN autograd (ms)",
                "baseline (ms)",
                "autograd / closed-form",
                "closed-form / baseline",
            ],
            rows,
        ),
    ]
    facts: dict[str, Any] = {"steps": res, "threads": thread_list, "shapes": shapes}
    if quick:
        body.append("\n`--quick`: 750×2, 1 thread only; Lightning and `torch.compile` skipped.")
    else:
        text, facts["lightning"] = _lightning_overhead(shapes, threads, n_steps, log)
        body += ["", "### Through Lightning\n", text]
        text, facts["compile"] = _compile_bench(threads, log)
        body += ["", "### torch.compile of the closed-form HNN loss\n", text]
    return Section("training", "2. Training step", "\n".join(body), facts)


def _lightning_overhead(shapes, threads, n_steps, log) -> tuple[str, dict]:
    import lightning as L

    from hnn_pl.cli import quiet_lightning
    from hnn_pl.data import TensorBatches
    from hnn_pl.models import HNN

    quiet_lightning()
    n_fit = 120

    class StepClock(L.Callback):
        def __init__(self) -> None:
            self.stamps: list[float] = []

        def on_train_batch_end(self, *args, **kwargs) -> None:
            self.stamps.append(time.perf_counter())

    rows, facts = [], {}
    for n, d, what in shapes:
        x, dx = _batch(n, d)
        with _threads(threads), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with torch.random.fork_rng():
                torch.manual_seed(0)
                model = HNN(input_dim=d)
            plain = copy.deepcopy(model.field)

            def loss_fn(plain=plain, x=x, dx=dx) -> Tensor:
                return nn.functional.mse_loss(plain.vector_field(None, x), dx)

            before = _step_times(loss_fn, plain.parameters(), n_steps)[0]
            clock = StepClock()
            trainer = L.Trainer(
                max_steps=n_fit,
                max_epochs=1,
                accelerator="cpu",
                devices=1,
                logger=False,
                enable_checkpointing=False,
                enable_progress_bar=False,
                enable_model_summary=False,
                num_sanity_val_steps=0,
                limit_val_batches=0,
                callbacks=[clock],
            )
            t0 = time.perf_counter()
            trainer.fit(model, train_dataloaders=TensorBatches((x, dx), None, repeats=n_fit))
            total = time.perf_counter() - t0
            after = _step_times(loss_fn, plain.parameters(), n_steps)[0]
        raw = statistics.median(before + after)
        steps = [b - a for a, b in zip(clock.stamps[5:-1], clock.stamps[6:])]
        per = statistics.median(steps)
        fixed = total - sum(b - a for a, b in zip(clock.stamps[:-1], clock.stamps[1:]))
        rows.append(
            [
                f"{n}×{d} ({what})",
                _ms(raw),
                _ms(per),
                f"{(per - raw) * 1e3:.2f}",
                f"{100 * (per - raw) / raw:.0f}",
                f"{fixed:.2f}",
            ]
        )
        facts[n, d] = (raw, per, fixed)
        log(f"  lightning {n}x{d}: {per * 1e3:.2f} ms/step, fixed {fixed:.2f}s")
    text = (
        f"`hnn_pl.models.HNN` (closed-form) in `Trainer.fit(max_steps={n_fit})`, logger, "
        "checkpointing, progress bar and model summary off, the batch served by "
        f"`TensorBatches` (full batch, {n_fit} repeats), {threads} thread(s). Per step: "
        "median interval between consecutive `on_train_batch_end` calls (steps 6…"
        f"{n_fit}), which includes `self.log('train/loss')` and the loop's bookkeeping; "
        f"plain loop: the same model's field and Adam, median of {n_steps} steps measured "
        f"just before and {n_steps} just after the fit. Fixed cost: "
        "the `fit` call's wall time minus the steps (trainer set-up, first step, "
        "teardown); `Trainer` construction and `import lightning` not included.\n\n"
        + _table(
            [
                "batch × dim",
                "plain loop (ms)",
                "in Trainer.fit (ms)",
                "overhead (ms/step)",
                "overhead (%)",
                "fit fixed cost (s)",
            ],
            rows,
        )
    )
    return text, facts


def _compile_bench(threads: int, log) -> tuple[str, tuple | str]:
    """``torch.compile`` of the closed-form HNN loss at 750×2, with a cold inductor cache."""
    n, d, n_steps = 750, 2, 40
    x, dx = _batch(n, d)
    cache = tempfile.mkdtemp(prefix="hnn_bench_inductor_")
    old = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = cache
    rows = []
    try:
        with _threads(threads):
            eager = _make_field("hnn closed-form", d)

            def eager_loss() -> Tensor:
                return nn.functional.mse_loss(eager.vector_field(None, x), dx)

            t_eager, _ = _step_times(eager_loss, eager.parameters(), n_steps)
            fld = _make_field("hnn closed-form", d)

            def loss(x: Tensor, dx: Tensor) -> Tensor:
                return nn.functional.mse_loss(fld.vector_field(None, x), dx)

            compiled = torch.compile(loss)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t_comp, first = _step_times(lambda: compiled(x, dx), fld.parameters(), n_steps)
            except Exception as err:  # noqa: BLE001 - report whatever compile raises
                msg = f"{type(err).__name__}: {str(err).strip().splitlines()[0][:200]}"
                log(f"  compile failed: {msg}")
                return f"`torch.compile` raised: `{msg}`", msg
        e, c = statistics.median(t_eager), statistics.median(t_comp)
        rows.append([f"{n}×{d}", threads, f"{first:.2f}", _ms(e), _ms(c), f"{e / c:.2f}"])
        log(f"  compile: first {first:.1f}s, {c * 1e3:.2f} vs {e * 1e3:.2f} ms")
        result = (first, e, c)
    finally:
        if old is None:
            os.environ.pop("TORCHINDUCTOR_CACHE_DIR", None)
        else:
            os.environ["TORCHINDUCTOR_CACHE_DIR"] = old
        shutil.rmtree(cache, ignore_errors=True)
    text = (
        "`torch.compile(loss)` (default inductor backend) of "
        "`loss(x, dy) = MSE(HamiltonianField(MLP(2, 1)).vector_field(None, x), dy)` with the "
        "closed-form gradient, so no double backward is involved; step as above (the "
        "backward pass is compiled too). First step: compile of forward and backward with "
        f"an empty inductor cache directory. Median of {n_steps} steps after 5 warm-up "
        "steps.\n\n"
        + _table(
            [
                "batch × dim",
                "threads",
                "first step (s)",
                "eager (ms)",
                "compiled (ms)",
                "speed-up",
            ],
            rows,
        )
    )
    return text, result


# ---------------------------------------------------------------------------------
# 3. data generation


def _data_tasks(quick: bool) -> list[tuple[str, Callable[[str], Any]]]:
    from hnn_pl.data import SimulatedData

    spring = {"n_trajectories": 50, "t_span": (0.0, 3.0), "n_points": 30, "noise_std": 0.1}
    pend = {"n_trajectories": 50, "t_span": (0.0, 3.0), "n_points": 45, "noise_std": 0.1}
    nbody = {"noise_std": 0.0, "test_fraction": 0.2, "test_first": True}
    two = {"n_trajectories": 1000, "t_span": (0.0, 20.0), "n_points": 50, **nbody}
    three = {"n_trajectories": 5000, "t_span": (0.0, 5.0), "n_points": 20, **nbody}
    tasks = [
        (
            "mass-spring (50 × 30, closed form)",
            lambda c: SimulatedData(MassSpring(), cache_dir=c, **spring),
        ),
        ("pendulum (50 × 45, dopri5)", lambda c: SimulatedData(Pendulum(), cache_dir=c, **pend)),
    ]
    if not quick:
        tasks += [
            (
                "two-body (1000 × 50, dopri5)",
                lambda c: SimulatedData(TwoBody(), cache_dir=c, **two),
            ),
            (
                "three-body (5000 × 20, dopri5)",
                lambda c: SimulatedData(ThreeBody(), cache_dir=c, **three),
            ),
        ]
    return tasks


def bench_data(quick: bool = False, log: Callable[[str], None] = print) -> Section:
    """Section 3: ``SimulatedData`` generation (empty cache) and cache-hit load time."""
    rows, facts = [], {}
    gen_repeats = 1 if quick else 3
    for name, make in _data_tasks(quick):
        gen_times, load_times = [], []
        n_rows = 0
        for _ in range(gen_repeats):
            with tempfile.TemporaryDirectory(prefix="hnn_bench_data_") as cache:
                dm = make(cache)
                t0 = time.perf_counter()
                dm.prepare_data()
                gen_times.append(time.perf_counter() - t0)
                if gen_times[-1] > 5 and not load_times:
                    gen_repeats = 1
                size = sum(p.stat().st_size for p in Path(cache).iterdir())
                for _ in range(5):
                    fresh = make(cache)
                    t0 = time.perf_counter()
                    fresh.setup()
                    load_times.append(time.perf_counter() - t0)
                n_rows = len(fresh.x_train) + len(fresh.x_test)
            if gen_repeats == 1:
                break
        g, ld = statistics.median(gen_times), statistics.median(load_times)
        rows.append(
            [name, n_rows, f"{g:.3f}", len(gen_times), f"{ld * 1e3:.2f}", f"{size / 1e6:.2f}"]
        )
        facts[name.split(" (")[0]] = (g, ld)
        log(f"  data {name}: {g:.2f}s, load {ld * 1e3:.1f}ms")
    body = (
        "`SimulatedData(...).prepare_data()` into an empty temporary `cache_dir` "
        "(sampling, float64 ground truth with the system's integrator at rtol = atol = 1e-10 "
        "or the closed form, noise, split, `torch.save`), the parameters of the bundled "
        "configs, the run's torch threads; then `setup()` of a fresh DataModule "
        "(cache hit: `torch.load` and the cast to float32), median of 5 loads per "
        "generation. Generation: median of `n` runs (one run when it takes over 5 s).\n\n"
        + _table(["task", "rows", "generate (s)", "n", "load cache (ms)", "cache file (MB)"], rows)
    )
    return Section("data", "3. Data generation", body, facts)


# ---------------------------------------------------------------------------------
# 4. start-up


def bench_startup(quick: bool = False, log: Callable[[str], None] = print) -> Section:
    """Section 4: wall time of fresh interpreters running the CLI help and imports."""
    py = sys.executable
    cmds = [
        ("`python -c pass` (interpreter alone)", [py, "-c", "pass"]),
        ("`python -m hnn_pl --help`", [py, "-m", "hnn_pl", "--help"]),
        (
            "`import hnn_pl; from hnn_pl import odeint`",
            [py, "-c", "import hnn_pl; from hnn_pl import odeint"],
        ),
    ]
    if not quick:
        cmds.append(("`from hnn_pl import HNN`", [py, "-c", "from hnn_pl import HNN"]))
    repeats = 1 if quick else 3
    env = dict(os.environ)
    rows, res = [], {}
    for name, cmd in cmds:
        times = []
        subprocess.run(cmd, capture_output=True, env=env, check=True)  # warm file cache
        for _ in range(repeats):
            t0 = time.perf_counter()
            subprocess.run(cmd, capture_output=True, env=env, check=True)
            times.append(time.perf_counter() - t0)
        res[name] = statistics.median(times)
        rows.append([name, f"{res[name]:.2f}", repeats])
        log(f"  startup {name}: {res[name]:.2f}s")
    byte = os.environ.get("PYTHONDONTWRITEBYTECODE")
    body = (
        f"Wall time of a fresh `{Path(py).name}` process, median of {repeats} runs after one "
        f"untimed run (warm file cache). `PYTHONDONTWRITEBYTECODE={byte or 'unset'}`.\n\n"
        + _table(["command", "time (s)", "n"], rows)
        + ("\n\n`--quick`: the `HNN` import (Lightning) skipped." if quick else "")
    )
    return Section("startup", "4. Start-up", body, res)


# ---------------------------------------------------------------------------------
# the report and the command line

BENCHMARKS: dict[str, Callable[..., Section]] = {
    "integrators": bench_integrators,
    "training": bench_training,
    "data": bench_data,
    "startup": bench_startup,
}


def _run_section(name: str, quick: bool, threads: int, log) -> Section:
    load0, t0 = _load1(), time.perf_counter()
    log(f"[{name}] load {load0:.2f}")
    if name == "training":
        section = bench_training(quick, threads, log)
    else:
        section = BENCHMARKS[name](quick, log=log)
    section.seconds = time.perf_counter() - t0
    section.load = (load0, _load1())
    log(f"[{name}] {section.seconds:.1f}s, load {section.load[1]:.2f}")
    return section


def _ratio_advice(ratio: float) -> str:
    if ratio >= 1.15:
        return "2 threads pay off"
    if ratio <= 0.87:
        return "1 thread is faster"
    return "no clear difference"


def _prose(sections: list[Section]) -> list[str]:
    """The summary paragraphs, written from the sections' measured facts."""
    by = {s.name: s.facts for s in sections}
    paras: list[str] = []
    label = {"pendulum": "pendulum", "hnn": "HNN"}
    if "integrators" in by:
        f = by["integrators"]
        parts = []
        for target in ERROR_TARGETS:
            items = []
            for name, batch in f["cases"]:
                r = f["pareto"][name, batch, target]
                what = f"{r.method} {r.setting} {r.dtype} {_ms(r.time)} ms" if r else "not reached"
                items.append(f"{label[name]} × {batch}: {what}")
            parts.append(f"- error ≤ {target:.0e}: " + "; ".join(items) + ".")
        text = (
            "**Integrators**: the fastest setting of the sweep reaching each max state "
            "error (t ∈ [0, 20], against a float64 DOP853 reference), per field × starts:\n\n"
            + "\n".join(parts)
            + "\n\n"
        )
        per, flat, dop = f["per_traj"]
        if per and flat and dop:
            text += (
                f"One `solve_ivp` call per trajectory, as the reference code does, took "
                f"{_ms(per.time)} ms for 25 pendulum starts at rtol = atol = 1e-6 (error "
                f"{_sci(per.error)}), {per.time / flat.time:.0f}× the {_ms(flat.time)} ms of "
                f"one call on the flattened batch (error {_sci(flat.error)}); torch dopri5 "
                f"{_ms(dop.time)} ms (error {_sci(dop.error)})."
            )
        paras.append(text)
    if "training" in by:
        f = by["training"]
        th = f["threads"][-1]
        res = f["steps"]
        items = []
        for n, d, _ in f["shapes"]:
            cf, ag, bl = (res[n, d, th, k] for k in ("hnn closed-form", "hnn autograd", "baseline"))
            items.append(
                f"{n}×{d}: {_ms(cf)} vs {_ms(ag)} ms (closed form {ag / cf:.2f}× as fast; "
                f"baseline {_ms(bl)} ms)"
            )
        text = (
            f"**Training step** (float32, {th} thread(s)), HNN with the closed-form input "
            "gradient vs autograd double backward, ms per optimiser step: " + "; ".join(items) + "."
        )
        if "lightning" in f:
            items = [
                f"{n}×{d}: {_ms(per)} vs {_ms(raw)} ms, +{(per - raw) * 1e3:.2f} ms "
                f"({100 * (per - raw) / raw:.0f} %)"
                for (n, d), (raw, per, fixed) in f["lightning"].items()
            ]
            fixed = [v[2] for v in f["lightning"].values()]
            text += (
                " Inside `Trainer.fit` vs a plain loop, per step: "
                + "; ".join(items)
                + f"; plus {min(fixed):.2f}–{max(fixed):.2f} s fixed cost per `fit`."
            )
        if "compile" in f:
            c = f["compile"]
            if isinstance(c, tuple):
                text += (
                    f" `torch.compile` of the closed-form loss (750×2): first step {c[0]:.1f} s, "
                    f"then {_ms(c[2])} vs {_ms(c[1])} ms eager ({c[1] / c[2]:.2f}×)."
                )
            else:
                text += f" `torch.compile` of the closed-form loss failed: `{c}`."
        paras.append(text)
    threads_items = []
    if "training" in by and len(by["training"]["threads"]) > 1:
        f = by["training"]
        hi = f["threads"][-1]
        for n, d, _ in f["shapes"]:
            r = f["steps"][n, d, 1, "hnn closed-form"] / f["steps"][n, d, hi, "hnn closed-form"]
            threads_items.append(f"HNN training step {n}×{d}: {r:.2f}× ({_ratio_advice(r)})")
    if "integrators" in by and "threads" in by["integrators"]:
        t = by["integrators"]["threads"]
        for batch in (25, 1000):
            r = t[batch, 1] / t[batch, 2]
            threads_items.append(f"HNN rk4 rollout, {batch} starts: {r:.2f}× ({_ratio_advice(r)})")
    if threads_items:
        paras.append(
            "**Threads** (speed with 2 torch threads relative to 1; > 1 means 2 are "
            "faster): "
            + "; ".join(threads_items)
            + ". These are the machine's state during this run; on a machine shared with "
            "other busy processes, 2 threads per process contend for the 2 cores, so there "
            "each process should use 1 (`torch.set_num_threads(1)`)."
        )
    if "data" in by or "startup" in by:
        items = []
        for name, (g, ld) in by.get("data", {}).items():
            items.append(f"{name} {g:.2f} s (cache hit {ld * 1e3:.1f} ms)")
        text = ""
        if items:
            text += "**Data generation**: " + "; ".join(items) + ". "
        if "startup" in by:
            text += "**Start-up** (fresh process): " + "; ".join(
                f"{name} {t:.2f} s" for name, t in by["startup"].items()
            )
            text += "."
        paras.append(text.strip())
    out = []
    for p in paras:
        out += [p, ""]
    return out


def render(sections: list[Section], info: dict[str, str], quick: bool, total: float) -> str:
    """The Markdown report."""
    out = ["# hnn_pl benchmarks", ""]
    out.append(
        "Written by `python -m hnn_pl.bench"
        + (" --quick" if quick else "")
        + "`. Run time against error of the integrators, training-step cost, data "
        "generation and start-up. Medians of repeated timings (repeat counts in each "
        "table); no number here is a test threshold, and numbers move from run to run: "
        "compare within one report."
    )
    out += ["", "## Machine", ""]
    out.append(_table(["", ""], [[k, v] for k, v in info.items()]))
    loads = ", ".join(f"{s.name} {s.load[0]:.2f} → {s.load[1]:.2f}" for s in sections)
    out += [
        "",
        f"1-minute load average before → after each section: {loads} (the benchmark "
        "itself keeps up to its thread count of cores busy, so a load near that during the "
        f"run is its own). Whole run: {total:.0f} s.",
        "",
        "## Summary (measured in this run)",
        "",
    ]
    out += _prose(sections)
    for s in sections:
        out += ["", f"## {s.title}", "", s.body]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """The command line; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m hnn_pl.bench",
        description="Benchmark hnn_pl and write a Markdown report.",
    )
    parser.add_argument("--quick", action="store_true", help="a seconds-long smoke run")
    parser.add_argument("--out", default="BENCHMARKS.md", help="report path (default %(default)s)")
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: torch's default)"
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=list(BENCHMARKS),
        metavar="NAME",
        help=f"run only these sections: {', '.join(BENCHMARKS)}",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    args = parser.parse_args(argv)
    if args.threads is not None:
        if args.threads < 1:
            parser.error("--threads must be >= 1")
        torch.set_num_threads(args.threads)
    threads = torch.get_num_threads()

    def log(msg: str) -> None:
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    info = machine_info(threads)
    t0 = time.perf_counter()
    sections = [_run_section(name, args.quick, threads, log) for name in (args.only or BENCHMARKS)]
    total = time.perf_counter() - t0
    report = render(sections, info, args.quick, total)
    Path(args.out).write_text(report)
    log(f"wrote {args.out} ({total:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
