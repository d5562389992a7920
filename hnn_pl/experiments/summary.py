"""Summarise, the second step of ``reproduce``: the records of the runs become one row
per task and model, median and worst over seeds of every number."""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable

from hnn_pl.experiments import paper


def median_worst(values: list[float]) -> tuple[float, float]:
    """Median and largest of the finite values (all our numbers are errors or times)."""
    values = [v for v in values if v is not None and math.isfinite(v)]
    return (statistics.median(values), max(values)) if values else (math.nan, math.nan)


def _abs(x: float | None) -> float | None:
    return None if x is None else abs(x)


#: a row's numbers (median and worst over seeds): how a record gives each
NUMBERS: dict[str, Callable[[dict], float | None]] = {
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
}


def timed(runs: list[dict]) -> list[dict]:
    """The runs that measured time to accuracy (not ``reproduce --no-tta``)."""
    return [r for r in runs if r.get("tta_measured", True)]


def time_to_accuracy(runs: list[dict]) -> str:
    """``median (worst) s, k/n reached``: time to the joint criterion of
    :class:`~hnn_pl.experiments.tta.TimeToAccuracy` (published HNN energy MSE and, where
    the task has one, the paper recipe's clean state MSE) over the runs that measured it."""
    runs = timed(runs)
    if not runs:
        return "not measured"
    secs = [r["tta"]["seconds"] if r.get("tta") else math.inf for r in runs]
    reached = sum(math.isfinite(s) for s in secs)
    if not reached:
        return f"not reached (0/{len(runs)})"
    med, worst = statistics.median(secs), max(secs)
    return f"{med:.1f} ({worst:.1f}) s, {reached}/{len(runs)}"


def _valid_time(runs: list[dict]) -> tuple[float, float]:
    """Median and *smallest* valid prediction time over the runs (``nan`` if none)."""
    vpts = [r["clean"].get("valid_time") for r in runs]
    vpts = [v for v in vpts if v is not None and math.isfinite(v)]
    return (statistics.median(vpts), min(vpts)) if vpts else (math.nan, math.nan)


def summarize(records: list[dict]) -> list[dict]:
    """One row per (task, model) in the paper's order: ``seeds`` and ``failed`` counts,
    median and worst over seeds of every :data:`NUMBERS` entry, ``valid_time`` (median,
    smallest), ``tta`` (:func:`time_to_accuracy`) and ``tta_state_targets`` (the state
    targets the timed runs used, sorted)."""
    rows = []
    for task in paper.PAPER:
        for model in paper.get(task).models:
            runs = [r for r in records if r["task"] == task and r["model"] == model]
            if not runs:
                continue
            ok = [r for r in runs if "error" not in r]
            row = {"task": task, "model": model, "seeds": len(ok), "failed": len(runs) - len(ok)}
            for key, get in NUMBERS.items():
                row[key] = median_worst([get(r) for r in ok if get(r) is not None])
            row["tta"] = time_to_accuracy(ok)
            row["valid_time"] = _valid_time(ok)
            targets = {r.get("tta_state_target", math.inf) for r in timed(ok)}
            row["tta_state_targets"] = sorted(targets)
            rows.append(row)
    return rows


def ratios(rows: list[dict]) -> list[tuple[str, float, float, float]]:
    """Baseline / HNN energy-MSE ratio of the medians, per task with both rows:
    ``(task, reference protocol, published, clean protocol)``."""
    by = {(r["task"], r["model"]): r for r in rows}
    out = []
    for task in paper.PAPER:
        if (task, "baseline") in by and (task, "hnn") in by:
            b, h = by[task, "baseline"], by[task, "hnn"]
            published = paper.get(task).published
            pub = published["baseline"].energy_mse / published["hnn"].energy_mse
            ref = b["ref_energy"][0] / h["ref_energy"][0]
            clean = b["clean_energy"][0] / h["clean_energy"][0]
            out.append((task, ref, pub, clean))
    return out
