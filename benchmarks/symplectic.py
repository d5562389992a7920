"""Implicit midpoint against dopri5 on trained HNNs: long-horizon energy error at equal
wall time, per state task.

Each task's fast-recipe HNN (seed 0) is rolled out from its clean protocol's held-out
starts (at most 20) over 10× the protocol's horizon, in float64, by dopri5 at three
tolerances and by the implicit midpoint rule (symplectic for any ``H_θ``) at three
steps. Scored: the true energy's error ``mean_{t,b} (E(y_t) − E(y_0))²`` (the truth
conserves ``E``, so no reference trajectory is needed over the long horizon) and the
learned ``H_θ``'s drift ``mean_b max_t |H_θ(y_t) − H_θ(y_0)|`` over its spread on the
training inputs. The real pendulum is left out: it has no truth beyond its 18 s record.
"""

from __future__ import annotations

import sys

import torch
from common import main, measure, quiet_cli, table

from hnn_pl import evaluation, rollout
from hnn_pl.evaluation.metrics import energy_conservation_mse, h_spread, h_spread_drift
from hnn_pl.experiments.paper import PAPER

TITLE = "Implicit midpoint against dopri5 on learned fields"
TASKS = ("spring", "pendulum", "two_body", "three_body")
DOPRI = (1e-4, 1e-6, 1e-8)
#: implicit-midpoint steps, at most the output spacing (a larger step is cut to it)
STEPS = {"spring": (0.1, 0.05, 0.025), "pendulum": (0.1, 0.05, 0.025)}
STEPS |= {"two_body": (0.1, 0.05, 0.025), "three_body": (0.025, 0.0125, 0.00625)}
#: a win needs an error below this fraction of the best rival's (the model's own error
#: dominates the true-energy MSE, and equal numbers must not count as wins)
MARGIN = 0.9


def trained(task: str, quick: bool):
    cli = quiet_cli(PAPER[task].config("hnn", "fast"), 0, 1, 20 if quick else None)
    cli.trainer.fit(cli.model, cli.datamodule)
    return cli.model, cli.datamodule


def score(model, dm, y0, t, method, **kw) -> tuple[float, float, float]:
    """Seconds, true-energy MSE (:func:`energy_conservation_mse`) and learned-H drift
    (mean over rows of :func:`h_spread_drift` by :func:`h_spread` over 4096 training
    inputs) of one rollout."""
    energy = dm.system.energy
    run = lambda: rollout(model, y0, t, method=method, energy=energy, **kw)  # noqa: E731
    seconds, _ = measure(run, min_run_time=0.5, once_above=0.3)
    traj = run()
    e_mse = float(energy_conservation_mse(traj.e_pred))
    dtype = next(model.parameters()).dtype
    scale = float(h_spread(model.field, dm.reference_inputs(4096).to(dtype)))
    drift = float(h_spread_drift(traj.h_pred, scale).mean())
    return seconds, e_mse, drift


def run(quick: bool = False) -> str:
    rows, verdicts = [], []
    for task in TASKS[:1] if quick else TASKS:
        model, dm = trained(task, quick)
        clean = evaluation.task_protocol(task, "clean")
        _, y_true = dm.rollout_target(clean.t_end, clean.n_points)
        y0 = y_true[0, :20].double()
        horizon = 10 * clean.t_end / (10 if quick else 1)
        t = torch.linspace(0, horizon, 10 * clean.n_points + 1, dtype=torch.float64)
        points = {"dopri5": [], "implicit_midpoint": []}
        for tol in DOPRI[1:2] if quick else DOPRI:
            s, e, d = score(model, dm, y0, t, "dopri5", rtol=tol, atol=tol)
            points["dopri5"].append((s, e, d))
            rows.append(
                [task, "dopri5", f"rtol = atol = {tol:.0e}", f"{s:.3f}", f"{e:.2e}", f"{d:.2e}"]
            )
        for h in STEPS[task][:1] if quick else STEPS[task]:
            s, e, d = score(model, dm, y0, t, "implicit_midpoint", step_size=h)
            points["implicit_midpoint"].append((s, e, d))
            rows.append(
                [task, "implicit_midpoint", f"h = {h:g}", f"{s:.3f}", f"{e:.2e}", f"{d:.2e}"]
            )
        wins = [0, 0]
        for s_im, *err_im in points["implicit_midpoint"]:
            for k in (0, 1):
                rivals = [p[1 + k] for p in points["dopri5"] if p[0] <= s_im]
                wins[k] += not rivals or err_im[k] < MARGIN * min(rivals)
        n = len(points["implicit_midpoint"])
        verdicts.append([task, f"{horizon:g}", f"{wins[0]}/{n}", f"{wins[1]}/{n}"])
        print(rows[-1], verdicts[-1], flush=True)
    head = "task | method | setting | seconds | true-energy MSE | learned-H drift"
    vhead = (
        "task | horizon | implicit-midpoint settings beating every dopri5 setting at most "
        "as slow by 10 %: true-energy MSE | the same: learned-H drift"
    )
    return (
        table(head, rows)
        + "\n\n"
        + table(vhead, verdicts)
        + "\n\n20 held-out starts, float64, 1 torch thread; seconds: median of repeated "
        "rollouts (`torch.utils.benchmark`)."
    )


if __name__ == "__main__":
    main({"symplectic": sys.modules[__name__]}, None)
