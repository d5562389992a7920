"""Render, the last step of ``reproduce``: ``RESULTS.md`` from the records and their
summary (:mod:`hnn_pl.experiments.summary`), ours beside the paper's numbers.

``python -m hnn_pl.experiments.results RESULTS_fast.json [--out PAGE.md]`` renders a
page again from its JSON records (no training): ``reproduce``'s pages and those of
``reproduce --recipe positions`` and ``--recipe priors`` alike."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path

from hnn_pl.experiments import paper
from hnn_pl.experiments.summary import ratios, summarize

#: what the report says of a task beside its numbers (``"results"``) and how its
#: protocols read (``"reference"``, ``"clean"``; else the protocol's fields)
NOTES: dict[str, dict[str, str]] = {
    "real_pendulum": {
        "results": (
            "dissipative: the dissipative HNN (`real_pendulum_dissipative.yaml`, no published"
            " number). On the paper's forward differences it learns the decay those "
            "differences add (energy slope ≈ −0.045 per s against the recording's −0.011, as "
            "the baseline does); on central differences it follows the recording (−0.011) and"
            " its energy MSE falls below the HNN's: docs/friction.md."
        ),
    },
    "pixel": {
        "reference": (
            "the reference's evaluation (analyze-pixels, 2019-05-20): one trajectory from θ₀ "
            "= 0.2934, θ̇₀ = 0.7326, its first frame pair encoded, the latent integrated over"
            " [0, 0.98·200] frames at 200 points, decoded, re-encoded and read by a linear "
            "probe fitted on the training set through the HNN's encoder (for the baseline "
            "too: `reproduce` pairs each baseline with the HNN of its seed; time to accuracy "
            "uses each model's own), H = 1.9(1 − cos q) + p²"
        ),
        "clean": (
            "all held-out 200-frame trajectories, each model its own encoder and probe, H = "
            "1.875(1 − cos q) + p²"
        ),
    },
}


def fmt(median: float, worst: float | None = None) -> str:
    """``median (worst)`` in two significant digits, ``median`` alone in four, ``—`` if NaN."""
    if math.isnan(median):
        return "—"
    return f"{median:.3e}" if worst is None or math.isnan(worst) else f"{median:.2e} ({worst:.2e})"


def write_markdown(records: list[dict], path: Path, meta: dict) -> None:
    """``RESULTS.md`` (:func:`render`) written atomically to ``path``."""
    from hnn_pl.safe_io import write_atomic

    write_atomic(path, render(records, meta).encode())


def render(records: list[dict], meta: dict) -> str:
    """``RESULTS.md``: per task and model, ours (median and worst over seeds) beside the
    paper's, then the long-horizon, motion, ratio, per-seed and protocol tables."""
    rows = summarize(records)
    lines = [
        *_results(rows, meta),
        *_long_horizons(rows),
        *_motion(rows),
        *_ratios(rows),
        *_per_seed(records, rows),
        *_protocols(records),
        *_failures(records),
        *_independent(rows),
    ]
    return "\n".join(lines) + "\n"


def _section(title: str, *intro: str) -> list[str]:
    return ["", f"## {title}", "", *intro]


def _header(meta: dict) -> list[str]:
    return [
        "# Results: Table 1 reproduced",
        "",
        f"Written by `python -m hnn_pl reproduce` on {meta['date']} ({meta['machine']}); "
        f"{meta['command']}. Total wall time {meta['total_s']:.0f} s "
        f"({meta['workers']} worker processes, 1 torch thread each; data generation "
        f"{sum(meta['data_s'].values()):.1f} s), recipe `{meta.get('recipe', 'paper')}`. "
        "Ours: median (worst) over seeds, each seed drawing its own data; published: "
        "the reference README (± there is over trials, not seeds). Time to accuracy: "
        "training seconds until a check (periodic, its own cost excluded) finds both the "
        "energy MSE on the paper's protocol at or below the published HNN value and the "
        "state MSE on the clean protocol at or below the paper recipe's HNN median "
        "(`hnn_pl.tasks`, `paper_motion`; runs made before a task had one: energy "
        "only, see the motion table's last column), median (worst) over the seeds, and "
        "how many seeds reached it.",
        *_calls(meta),
    ]


def _calls(meta: dict) -> list[str]:
    """One sentence on the earlier calls whose runs this page merges (their commands,
    dates and times stay in the JSON file's ``meta.earlier_calls``)."""
    n = len(meta.get("earlier_calls", []))
    if not n:
        return []
    return [
        "",
        f"The runs come from {n + 1} calls of `reproduce --merge`; each call's command, date "
        "and wall time are in the JSON records beside this page (`meta.earlier_calls`).",
    ]


def _results(rows: list[dict], meta: dict) -> list[str]:
    lines = [
        *_header(meta),
        "",
        "| task | model | seeds | train loss (ours / paper) | test loss (ours / paper) "
        "| energy MSE, reference protocol (ours / paper) | energy MSE, clean protocol "
        "| HNN-conserved drift (clean) | train s | eval s | time to accuracy |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        pub = paper.get(row["task"]).published.get(row["model"])
        theirs = ["—"] * 3 if pub is None else [fmt(pub[0]), fmt(pub[1]), fmt(pub[2], pub[3])]
        fail = f" ({row['failed']} failed)" if row["failed"] else ""
        lines.append(
            f"| {row['task']} | {row['model']} | {row['seeds']}{fail} "
            f"| {fmt(*row['train_loss'])} / {theirs[0]} "
            f"| {fmt(*row['test_loss'])} / {theirs[1]} "
            f"| {fmt(*row['ref_energy'])} / {theirs[2]} "
            f"| {fmt(*row['clean_energy'])} | {fmt(*row['clean_drift'])} "
            f"| {row['train_s'][0]:.1f} | {row['eval_s'][0]:.1f} | {row['tta']} |"
        )
    notes = {row["task"]: NOTES.get(row["task"], {}).get("results") for row in rows}
    return lines + [f"\n**{task}.** {note}" for task, note in notes.items() if note]


def _long_horizons(rows: list[dict]) -> list[str]:
    lines = _section(
        "Long horizons (clean protocol)",
        "Valid prediction time: the first time the normalised state error "
        "‖y_pred − y_true‖ / rms ‖y_true‖ passes 0.025 (the whole horizon if never), mean "
        "over trajectories; energy drift: least-squares slope in time of the predicted "
        "energy's relative change, absolute. Error split: the model's energy MSE beside "
        "the integrator floor (the true system through the same method and step) and "
        "the chaos floor (the true system from starts perturbed by 1e-4). Median (worst) "
        "over seeds.",
        "",
        "| task | model | valid prediction time | energy drift per unit time "
        "| energy MSE (model) | integrator floor | chaos floor |",
        "|---|---|---|---|---|---|---|",
    )
    for row in rows:
        vpt_med, vpt_worst = row["valid_time"]
        if math.isnan(vpt_med):
            continue
        lines.append(
            f"| {row['task']} | {row['model']} | {vpt_med:.3g} ({vpt_worst:.3g}) "
            f"| {fmt(*row['clean_slope'])} | {fmt(*row['clean_energy'])} "
            f"| {fmt(*row['floor_integrator'])} | {fmt(*row['floor_chaos'])} |"
        )
    return lines


def _motion(rows: list[dict]) -> list[str]:
    lines = _section(
        "Motion (clean protocol)",
        "State MSE: `mean_{t,b,d} (y_pred − y_true)²` over the held-out rollouts; field "
        "error: `sqrt(Σ ‖f_θ(y) − f(y)‖²) / sqrt(Σ ‖f(y)‖²)` summed over every true state "
        "`y` of the held-out trajectories (`hnn_pl.evaluation.metrics.field_error`; the real "
        "pendulum's `f` is the recording's central differences; pixel models: not "
        "applicable, their latent field has no true counterpart); valid prediction time "
        "as above (median, and the smallest over seeds). Median (worst) over the seeds "
        "that report each number (runs older than the field error have none). "
        "Target: the paper recipe's HNN medians (state MSE / field error) from "
        "`hnn_pl.tasks`; the state MSE target is the state half of time to accuracy.",
        "",
        "| task | model | state MSE | field error | valid prediction time "
        "| energy MSE (clean) | target: paper recipe HNN state MSE / field error "
        "| time-to-accuracy state target of these runs |",
        "|---|---|---|---|---|---|---|---|",
    )
    for row in rows:
        task = paper.get(row["task"])
        med, smallest = row["valid_time"]
        vpt = "—" if math.isnan(med) else f"{med:.3g} ({smallest:.3g})"
        field = fmt(*row["clean_field"]) if task.has_true_field else "n/a"
        motion = task.paper_motion
        target = "—" if motion is None else f"{motion.state_mse:.3g} / {fmt(motion.field_error)}"
        used = row["tta_state_targets"]
        used = ", ".join("none" if not math.isfinite(u) else f"{u:.3g}" for u in used) or "—"
        lines.append(
            f"| {row['task']} | {row['model']} | {fmt(*row['clean_state'])} | {field} "
            f"| {vpt} | {fmt(*row['clean_energy'])} | {target} | {used} |"
        )
    return lines


def _ratios(rows: list[dict]) -> list[str]:
    lines = _section(
        "Baseline / HNN energy-MSE ratio",
        "| task | reference protocol (ours) | paper | clean protocol (ours) |",
        "|---|---|---|---|",
    )
    for task, ref, pub, clean in ratios(rows):
        lines.append(f"| {task} | {ref:.3g} | {pub:.3g} | {clean:.3g} |")
    return lines


#: the per-seed tables' columns: header, how a record gives the number (``None``: not
#: measured), and how it reads
PER_SEED: tuple[tuple[str, Callable[[dict], float | None], str], ...] = (
    ("train loss", lambda r: r["train_loss"], ".2e"),
    ("test loss", lambda r: r["test_loss"], ".2e"),
    ("energy MSE, reference", lambda r: r["reference"]["energy_mse"], ".2e"),
    ("energy MSE, clean", lambda r: r["clean"]["energy_mse"], ".2e"),
    ("state MSE, clean", lambda r: r["clean"].get("state_mse"), ".2e"),
    ("field error", lambda r: r["clean"].get("field_error"), ".2e"),
    ("pixel MSE", lambda r: r["clean"].get("pixel_mse"), ".2e"),
    ("valid time", lambda r: r["clean"].get("valid_time"), ".3g"),
    ("train s", lambda r: r["train_s"], ".1f"),
)


def _per_seed(records: list[dict], rows: list[dict]) -> list[str]:
    """Per task, a collapsible table: one line per model and seed with every number of
    :data:`PER_SEED` the task's runs report (failed runs: ``failed``)."""
    lines = _section(
        "Per seed",
        "Every run's own numbers, so that one seed's run can be found beside the medians "
        "above (each seed draws its own data; a single seed can sit far from the median).",
    )
    for task in dict.fromkeys(row["task"] for row in rows):
        runs = sorted(
            (r for r in records if r["task"] == task),
            key=lambda r: ([row["model"] for row in rows].index(r["model"]), r["seed"]),
        )
        ok = [r for r in runs if "error" not in r]
        columns = [c for c in PER_SEED if any(c[1](r) is not None for r in ok)]
        lines += [
            "",
            '<details markdown="1">',
            f"<summary>{task}: {len(runs)} runs</summary>",
            "",
            "| task | model | seed | " + " | ".join(c[0] for c in columns) + " |",
            "|---" * (3 + len(columns)) + "|",
        ]
        for r in runs:
            cells = ["failed"] * len(columns) if "error" in r else [_cell(r, c) for c in columns]
            lines.append(f"| {task} | {r['model']} | {r['seed']} | " + " | ".join(cells) + " |")
        lines += ["", "</details>"]
    return lines


def _cell(record: dict, column: tuple[str, Callable[[dict], float | None], str]) -> str:
    value = column[1](record)
    return "—" if value is None or math.isnan(value) else format(value, column[2])


def _protocols(records: list[dict]) -> list[str]:
    from hnn_pl.evaluation import describe, task_protocol

    lines = _section(
        "Protocols",
        "Reference: the published procedure with its quirks (`hnn_pl.tasks`); "
        "scipy RK45, one `solve_ivp` call per model on the flattened batch of starts. "
        "Clean: held-out starts, the task's energy, float64 per-trajectory `dopri5` at "
        "rtol = atol = 1e-9, ground truth at 1e-10 (`hnn_pl.tasks`).",
        "",
        "| task | reference | clean |",
        "|---|---|---|",
    )
    for name in dict.fromkeys(r["task"] for r in records):
        ref, clean = (
            NOTES.get(name, {}).get(k) or describe(task_protocol(name, k))
            for k in ("reference", "clean")
        )
        lines.append(f"| {name} | {ref} | {clean} |")
    return lines


def _failures(records: list[dict]) -> list[str]:
    failures = [r for r in records if "error" in r]
    if not failures:
        return []
    lines = _section("Failed runs")
    for r in failures:
        last = r["error"].strip().splitlines()[-1]
        lines.append(f"- {r['task']} {r['model']} seed {r['seed']}: `{last}`")
    return lines


def _independent(rows: list[dict]) -> list[str]:
    indep = [row for row in rows if not math.isnan(row["indep_energy"][0])]
    if not indep:
        return []
    lines = _section(
        "True-energy evaluation (independent)",
        "The published procedure without its quirks (15 starts with each coordinate in "
        "±[0.2, 1], scipy RK45 at rtol = atol = 1e-12 on a float64 copy, t ∈ [0, 20], no "
        "time stretch, the system's true energy), as `benchmarks/independent.py`.",
        "",
        "| task | model | energy MSE, true energy |",
        "|---|---|---|",
    )
    return lines + [f"| {r['task']} | {r['model']} | {fmt(*r['indep_energy'])} |" for r in indep]


def render_file(json_path: Path, out: Path | None = None) -> Path:
    """The page of a JSON record file written by ``reproduce`` (``{"meta", "runs"}``)
    rendered again, to ``out`` (default: the JSON file's ``.md`` sibling); its path.
    ``reproduce --recipe positions``'s records (rows with a ``row``) and ``--recipe
    priors``'s (``meta.recipe``) render as their pages."""
    from hnn_pl.safe_io import write_atomic

    data = json.loads(json_path.read_text())
    records, meta = data["runs"], data["meta"]
    if meta.get("recipe") == "priors":
        from hnn_pl.experiments import priors

        page = priors.render(records, meta)
    elif records and "row" in records[0]:
        from hnn_pl.experiments import positions

        page = positions.render(positions.summarise(records), records, meta)
    else:
        page = render(records, meta)
    out = out or json_path.with_suffix(".md")
    write_atomic(out, page.encode())
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m hnn_pl.experiments.results FILE.json … [--out PAGE.md]``."""
    parser = argparse.ArgumentParser(
        prog="python -m hnn_pl.experiments.results",
        description="Render RESULTS pages again from their JSON records (no training).",
    )
    parser.add_argument("json", type=Path, nargs="+", help="records written by reproduce")
    parser.add_argument("--out", type=Path, help="the page (one JSON file only; default: .md)")
    args = parser.parse_args(argv)
    if args.out and len(args.json) > 1:
        parser.error("--out takes one JSON file")
    for path in args.json:
        print(f"wrote {render_file(path, args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
