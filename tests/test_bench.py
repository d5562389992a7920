"""The benchmark command: a ``--quick`` run writes a well-formed report.

No assertion here is about time: only the report's structure and the accuracy
ordering of the rows it measured (smaller steps and tighter tolerances give smaller
errors).
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hnn_pl.bench import BENCHMARKS, CountingField, time_call


def _tables(text: str) -> list[tuple[list[str], list[list[str]]]]:
    """Every Markdown table of ``text`` as (header, rows of cells)."""
    tables, lines, i = [], text.splitlines(), 0
    while i < len(lines) - 1:
        if lines[i].startswith("|") and re.fullmatch(r"\|(---\|)+", lines[i + 1]):
            header = [c.strip() for c in lines[i].strip("|").split("|")]
            rows, i = [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append([c.strip() for c in lines[i].strip("|").split("|")])
                i += 1
            assert all(len(r) == len(header) for r in rows), header
            tables.append((header, rows))
        else:
            i += 1
    return tables


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("bench") / "bench.md"
    cmd = [sys.executable, "-m", "hnn_pl.bench", "--quick", "--quiet", "--threads", "1"]
    cmd += ["--only", "integrators", "--out", str(out)]
    subprocess.run(cmd, check=True, timeout=120, cwd=Path(__file__).parents[1])
    return out.read_text()


def test_report_header(report):
    assert report.startswith("# hnn_pl benchmarks")
    for heading in ("## Machine", "## Summary", "## 1. Integrators"):
        assert heading in report
    machine = dict((r[0], r[1]) for r in _tables(report)[0][1])
    assert machine["torch threads"] == "1"
    assert machine["CPU"] and "logical" in machine["cores"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", machine["date"])
    assert "## 2." not in report  # --only


def test_integrator_table(report):
    tables = [t for t in _tables(report) if t[0][:3] == ["method", "setting", "dtype"]]
    assert len(tables) == 1
    header, rows = tables[0]
    col = {name: i for i, name in enumerate(header)}
    methods = {r[col["method"]] for r in rows}
    expected = {"rk4", "leapfrog", "implicit_midpoint", "dopri5", "scipy RK45, batch"}
    assert expected <= methods
    by_method: dict[str, list[tuple[float, float]]] = {}
    for r in rows:
        assert r[col["time (ms)"]] != "failed", r
        assert float(r[col["time (ms)"]]) > 0 and int(r[col["n"]]) >= 1
        assert int(r[col["calls"]]) > 0 and float(r[col["evals/traj"]]) > 0
        err, drift = float(r[col["max error"]]), float(r[col["energy drift"]])
        assert math.isfinite(err) and math.isfinite(drift) and err >= 0
        value = float(r[col["setting"]].split("=")[1])
        if r[col["dtype"]] == "float64":
            by_method.setdefault(r[col["method"]], []).append((value, err))
    # the 20-step rows are sorted by time; errors must fall as h or tol shrinks
    for method in expected:
        pairs = sorted(by_method[method], reverse=True)
        assert len(pairs) >= 2, method
        errors = [e for _, e in pairs]
        assert all(b < a for a, b in zip(errors, errors[1:])), (method, pairs)


def test_pareto_table(report):
    tables = [t for t in _tables(report) if "fastest setting" in t[0]]
    assert len(tables) == 1
    header, rows = tables[0]
    assert [r[2] for r in rows] == ["1e-03", "1e-06", "1e-09"]
    first = rows[0]
    assert first[3].split()[0] in {"rk4", "leapfrog", "implicit_midpoint", "dopri5", "scipy"}
    assert float(first[5]) <= 1e-3 and float(first[4]) > 0


def test_helpers():
    calls = []
    times, out = time_call(lambda: calls.append(1) or 7, min_time=0.0, max_repeats=3)
    assert out == 7 and len(times) == 2 and len(calls) == 3  # warm-up + 2 timed
    field = CountingField(lambda t, y: y)
    import torch

    field(0.0, torch.zeros(5, 2))
    field(0.0, torch.zeros(3, 2))
    assert (field.calls, field.rows) == (2, 8)
    assert set(BENCHMARKS) == {"integrators", "training", "data", "startup"}
