"""Run time against error of every ``hnn_pl.odeint`` method and scipy's RK45.

Fields: the true pendulum and an HNN fitted to it; 25 and 1000 starts; float32 and
float64; error against a float64 DOP853 reference at rtol = atol = 1e-13.
"""

from __future__ import annotations

import copy
import sys
import warnings
from collections import namedtuple

import torch
from common import main, measure, ms, table

from hnn_pl.evaluation.metrics import max_abs_error, max_energy_drift
from hnn_pl.integrate import odeint, scipy_odeint
from hnn_pl.nets import MLP, HamiltonianField
from hnn_pl.systems import Pendulum

TITLE = "Integrators: run time against error"
F32, F64 = torch.float32, torch.float64
FIXED = ("rk4", "leapfrog", "implicit_midpoint")
PER, FLAT = "scipy RK45, per trajectory", "scipy RK45, batch"
TARGETS = (1e-3, 1e-6, 1e-9)
H = (0.1, 0.05, 0.02, 0.01)
TOL32, TOL64 = (1e-4, 1e-5, 1e-6, 1e-7), tuple(10.0**-k for k in range(4, 11))
Row = namedtuple("Row", "name starts method setting dtype sec runs calls err drift")


def sweeps(quick: bool) -> dict:
    """``{(field, starts): {dtype: {method: step sizes or tolerances}}}``."""
    if quick:
        tols = (1e-4, 1e-6)
        quick = {**dict.fromkeys(FIXED, (0.1, 0.05)), "dopri5": tols, FLAT: tols, PER: (1e-4,)}
        return {("pendulum", 25): {F64: quick}}
    f32 = {**dict.fromkeys(FIXED, H[:3]), "dopri5": TOL32, FLAT: TOL32}
    f64 = {**dict.fromkeys(FIXED, H), "dopri5": TOL64, FLAT: TOL64}
    # one HNN evaluation of 1000 states costs milliseconds: a coarse float32 sweep there
    coarse = {"rk4": (0.1, 0.05), "leapfrog": (0.1,), "dopri5": (1e-4, 1e-6), FLAT: (1e-4,)}
    hnn64 = {**f64, **dict.fromkeys(FIXED, H[:3])}
    # float64 settings that can reach the 1e-9 target (dopri5's error is ~10³× its tol)
    pend64 = {**f64, "rk4": (*H, 0.005, 0.0025), "dopri5": (*TOL64, 1e-13)}
    return {
        ("pendulum", 25): {F32: f32, F64: {**pend64, PER: (1e-4, 1e-6)}},
        ("pendulum", 1000): {F32: f32, F64: pend64},
        ("hnn", 25): {F32: f32, F64: {**hnn64, PER: (1e-4,)}},
        ("hnn", 1000): {F32: coarse},
    }


def solver(method: str, v: float):
    if method in FIXED:
        return lambda f, y0, t: odeint(f, y0, t, method, step_size=v)
    if method == "dopri5":
        return lambda f, y0, t: odeint(f, y0, t, "dopri5", rtol=v, atol=v)

    def scipy(f, y0, t):
        rows = [y0[i : i + 1] for i in range(len(y0))] if method == PER else [y0]
        return torch.cat([scipy_odeint(f, y, t, "RK45", y0.dtype, rtol=v, atol=v) for y in rows], 1)

    return scipy


def fitted_hnn() -> HamiltonianField:
    """``HamiltonianField(MLP(2, 1))`` fitted (400 Adam steps) to the pendulum's J∇H on
    512 states in [−2.6, 2.6]², so its orbits have a trained HNN's time scales."""
    torch.manual_seed(0)
    hnn = HamiltonianField(MLP(2, 1))
    x = (torch.rand(512, 2) * 2 - 1) * 2.6
    dx = Pendulum().vector_field(None, x)
    opt = torch.optim.Adam(hnn.parameters(), lr=1e-3)
    for _ in range(400):
        opt.zero_grad()
        torch.nn.functional.mse_loss(hnn(x), dx).backward()
        opt.step()
    return hnn.requires_grad_(False)


def time_setting(f, method: str, v: float, y0, t, min_run_time: float):
    """Median seconds, timed runs, field calls per solve, and the solution."""
    solve, calls, out = solver(method, v), [0], {}

    def field(s, y):
        calls[0] += 1
        return f(s, y)

    def run():
        calls[0] = 0
        out["y"] = solve(field, y0, t)

    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # leapfrog on the non-separable H_θ
        sec, n = measure(run, min_run_time)
    return sec, n, calls[0], out["y"]


def sweep_case(name, starts, spec, fields, energy, y0_all, t, ref, quick) -> list[Row]:
    rows, n_err, mrt = [], min(starts, 25) if name == "hnn" else starts, 0.1 if quick else 0.25
    y0 = y0_all[:starts]
    e0 = energy(y0[:n_err])
    scale = e0.abs() if name == "pendulum" else e0.std()
    settings = [(d, m, v) for d, by_m in spec.items() for m, vs in by_m.items() for v in vs]
    for dtype, method, v in settings:
        sec, n, calls, y = time_setting(fields[dtype], method, v, y0.to(dtype), t.to(dtype), mrt)
        y = y[:, :n_err].double()
        err = float(max_abs_error(y, ref[:, :n_err]))
        drift = float(max_energy_drift(energy(y), e0, scale))
        setting = f"h={v:g}" if method in FIXED else f"tol={v:.0e}"
        rows.append(Row(name, starts, method, setting, str(dtype)[6:], sec, n, calls, err, drift))
        print(*rows[-1][:5], f"{sec:.3f} s", file=sys.stderr)
    return rows


def run(quick: bool) -> str:
    t = torch.linspace(0, 20, 201, dtype=F64)
    pend = Pendulum()
    y0_all = pend.sample_initial(1000, torch.Generator().manual_seed(0))
    fields = {"pendulum": ({F32: pend.vector_field, F64: pend.vector_field}, pend.hamiltonian)}
    if not quick:
        hnn32 = fitted_hnn()
        hnn64 = copy.deepcopy(hnn32).double()
        fields["hnn"] = ({F32: hnn32.vector_field, F64: hnn64.vector_field}, hnn64.hamiltonian)
    refs, rows = {}, []
    for (name, starts), spec in sweeps(quick).items():
        n_ref = starts if name == "pendulum" else 25
        if (name, n_ref) not in refs:
            f = fields[name][0][F64]
            refs[name, n_ref] = scipy_odeint(f, y0_all[:n_ref], t, "DOP853", rtol=1e-13, atol=1e-13)
        ref = refs[name, n_ref]
        rows += sweep_case(name, starts, spec, *fields[name], y0_all, t, ref, quick)
    header = "method | setting | dtype | time (ms) | runs | calls | max error | energy drift"
    parts = [
        "t ∈ [0, 20], 201 output times, starts `Pendulum().sample_initial(1000, seed 0)` "
        "(25 starts: the first 25), 1 torch thread, under `torch.no_grad`. Time: median "
        "(`torch.utils.benchmark` `blocked_autorange` after a warm-up run; a warm-up run of "
        "0.5 s or more is the only run). Calls: field calls per solve. Max error: max "
        "|y − y_ref| over times, starts and coordinates (HNN × 1000: the first 25 starts); "
        "y_ref: scipy DOP853 at rtol = atol = 1e-13, float64, same field. Energy drift: max "
        "|E(t) − E(0)| / |E(0)| (HNN: / std of H_θ(y0)). HNN: `HamiltonianField(MLP(2, 1))` "
        "fitted to the pendulum field."
    ]
    pareto, cmp, by_key = [], [], {r[:5]: r for r in rows}
    for name, starts in sweeps(quick):
        case = [r for r in rows if r[:2] == (name, starts)]
        cells = [
            [*r[2:5], ms(r.sec), r.runs, r.calls, f"{r.err:.2e}", f"{r.drift:.2e}"] for r in case
        ]
        parts += [f"### {name} field, {starts} starts", table(header, cells)]
        for target in TARGETS:
            best = min((r for r in case if r.err <= target), key=lambda r: r.sec, default=None)
            low = f"(smallest {min(r.err for r in case):.2e})"
            what = (
                [" ".join(best[2:5]), ms(best.sec), f"{best.err:.2e}"]
                if best
                else ["none", "", low]
            )
            pareto.append([name, starts, f"{target:.0e}", *what])
        for r in case:
            if r.method == PER:
                same = [by_key.get((name, starts, m, *r[3:5])) for m in (PER, FLAT, "dopri5")]
                cmp.append(
                    [
                        name,
                        starts,
                        *r[3:5],
                        *(f"{ms(x.sec)} ({x.err:.1e})" if x else "" for x in same),
                    ]
                )
    parts += [
        "### Fastest setting per error target",
        "The fastest row above with max error ≤ the target (float32 and float64 compete).",
        table("field | starts | error ≤ | fastest setting | time (ms) | error", pareto),
        "### scipy per trajectory vs flattened batch",
        "Time in ms (max error) at the same rtol = atol, from the tables above.",
        table(
            "field | starts | setting | dtype | one solve_ivp per start | one solve_ivp, "
            "flattened | torch dopri5",
            cmp,
        ),
    ]
    if not quick:
        parts += ["### Threads", threads_table(hnn32.vector_field, y0_all)]
    return "\n\n".join(parts)


def threads_table(field, y0_all) -> str:
    out, t = [], torch.linspace(0, 2, 21)
    for starts in (25, 1000):
        y0 = y0_all[:starts].float()
        for n in (1, 2):
            with torch.no_grad():
                sec, runs = measure(
                    lambda y0=y0: odeint(field, y0, t, "rk4", step_size=0.1), 0.25, n
                )
            out.append([starts, n, ms(sec), runs])
    caption = "HNN field, rk4 h = 0.1, t ∈ [0, 2] (80 field calls), float32, 1 and 2 torch threads."
    return caption + "\n\n" + table("starts | threads | time (ms) | runs", out)


if __name__ == "__main__":
    main({"integrators": sys.modules[__name__]}, None)
