"""Smoke test of ``benchmarks/``: a ``--quick`` run updates a report's marked sections.

Nothing here is about time: only the report's structure, that the hand-written text
outside the markers survives, and the accuracy ordering of the integrator rows
(smaller steps and tighter tolerances give smaller errors).

Here the topics that measure without training (``--quick --only`` :data:`UNTRAINED`,
about 30 s); the topics that train and score models first (:data:`TRAINED`, about 70 s
more) in tests/test_bench_trained.py, on a report of their own (two files, so the two
workers share them). Both are in the ``slow`` tier (``make test-all``) and run on the
suite's data cache (``HNN_PL_CACHE``), never the user's.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
#: the topics this file runs: timings and data, no model trained to be scored
UNTRAINED = (
    "integrators",
    "training",
    "data",
    "startup",
    "tta",
    "threads",
    "observer",
    "lagrangian",
    "chain_fit",
)
#: the topics tests/test_bench_trained.py runs (``slow``)
TRAINED = ("symplectic", "independent", "trajectory", "positions")
SECTIONS = ("machine", *UNTRAINED)
SEEDED = """# hnn_pl benchmarks

Hand-written introduction.

## Integrators

Hand-written integrator note.

<!-- begin integrators -->
stale table
<!-- end integrators -->

## Test-time augmentation

<!-- begin other -->
| written | by another script |
|---|---|
<!-- end other -->
"""


def tables(text: str) -> list[tuple[list[str], list[list[str]]]]:
    """Every Markdown table of ``text`` as (header, rows of cells), checked well-formed."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        if lines[i].startswith("|"):
            assert re.fullmatch(r"\|(---\|)+", lines[i + 1]), lines[i : i + 2]
            header = [c.strip() for c in lines[i].strip("|").split("|")]
            rows, i = [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append([c.strip() for c in lines[i].strip("|").split("|")])
                assert len(rows[-1]) == len(header), (header, rows[-1])
                i += 1
            out.append((header, rows))
        else:
            i += 1
    return out


def quick_report(out: Path, topics: tuple[str, ...], cache: Path) -> str:
    """``benchmarks/run.py --quick --only TOPICS --out OUT`` on the data cache ``cache``;
    the updated report's text."""
    cmd = [sys.executable, "benchmarks/run.py", "--quick", "--out", str(out), "--only", *topics]
    env = {**os.environ, "HNN_PL_CACHE": str(cache)}
    subprocess.run(cmd, check=True, timeout=600, cwd=REPO, env=env, capture_output=True)
    return out.read_text()


def section_bodies(report: str, names: tuple[str, ...]) -> dict[str, str]:
    """The text between each of ``names``' markers, each present exactly once."""
    for name in names:
        assert report.count(f"<!-- begin {name} -->") == report.count(f"<!-- end {name} -->") == 1
    return {n: report.split(f"<!-- begin {n} -->")[1].split(f"<!-- end {n} -->")[0] for n in names}


def has_headers(report: str, needles: tuple[str, ...]) -> None:
    """Every one of ``needles`` is in some table's header."""
    headers = [" ".join(h) for h, _ in tables(report)]
    for needle in needles:
        assert any(needle in h for h in headers), needle


@pytest.fixture(scope="module")
def report(tmp_path_factory, data_cache) -> str:
    out = tmp_path_factory.mktemp("bench") / "BENCHMARKS.md"
    out.write_text(SEEDED)
    return quick_report(out, UNTRAINED, data_cache)


def test_sections_and_hand_written_text(report):
    starts = [report.index(f"<!-- begin {name} -->") for name in (*SECTIONS, "other")]
    bodies = section_bodies(report, (*SECTIONS, "other"))
    assert starts[1] < starts[-1]  # the seeded integrators section was replaced in place
    assert "Hand-written introduction." in report and "Hand-written integrator note." in report
    assert "stale table" not in report and "| written | by another script |" in report
    assert not any(f"<!-- begin {name} -->" in report for name in TRAINED)  # --only
    assert all(tables(body) for body in bodies.values())  # every section has a table
    machine = dict(tables(bodies["machine"])[0][1])
    assert machine["torch"] and "logical" in machine["cores"]


def test_integrator_accuracy_ordering(report):
    (header, rows), *_ = [t for t in tables(report) if t[0][:2] == ["method", "setting"]]
    col = {name: i for i, name in enumerate(header)}
    by_method: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for r in rows:
        assert float(r[col["time (ms)"]]) > 0 and int(r[col["calls"]]) > 0
        value = float(r[col["setting"]].split("=")[1])
        by_method.setdefault((r[col["method"]], r[col["dtype"]]), []).append(
            (value, float(r[col["max error"]]))
        )
    assert {m for m, _ in by_method} >= {"rk4", "leapfrog", "implicit_midpoint", "dopri5"}
    for key, pairs in by_method.items():
        errors = [e for _, e in sorted(pairs, reverse=True)]  # largest step/tolerance first
        assert all(b < a for a, b in zip(errors, errors[1:])), (key, pairs)
    (_, pareto), *_ = [t for t in tables(report) if "fastest setting" in t[0]]
    assert [r[2] for r in pareto] == ["1e-03", "1e-06", "1e-09"]


def test_other_tables(report):
    has_headers(report, ("one solve_ivp per start", "HNN autograd (ms)", "in Trainer.fit (ms)"))
    has_headers(report, ("cache hit (ms)", "command time (s)", "seeds reached", "busy / idle"))


def test_chain_fit_rows_add_up(report):
    """Each 800-chunk config's row: its own max_steps, matrix products within the step,
    and the fit's estimate steps × step."""
    (header, rows), *_ = [t for t in tables(report) if "steps × step (s)" in t[0]]
    col = {name: i for i, name in enumerate(header)}
    assert [r[col["config"]] for r in rows] == [
        "`chain2.yaml`",
        "`chain2_mechanical_hnn.yaml`",
        "`chain2_mechanical_hnn_fast.yaml`",
    ]
    assert [int(r[col["steps"]]) for r in rows] == [8000, 8000, 4500]
    for r in rows:
        step = float(r[col["step (ms)"]])
        assert 0 < float(r[col["of which matrix products (ms)"]]) < step
        estimate = int(r[col["steps"]]) * step / 1e3
        assert float(r[col["steps × step (s)"]]) == pytest.approx(estimate, rel=0.01, abs=1)
