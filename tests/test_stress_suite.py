"""``python -m hnn_pl stress --quick`` writes the stability report, and its numbers say
what the physics says: symplectic methods bounded, rk4 and dopri5 drifting."""

from __future__ import annotations

import pytest

from hnn_pl.commands import stress as stress_command
from hnn_pl.experiments import stress
from hnn_pl.systems import MassSpring, Pendulum


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("stress") / "S.md"
    assert stress_command.main(["--quick", "--out", str(out)]) == 0
    return out


def _rows(text: str, first: str) -> list[list[str]]:
    return [
        [c.strip() for c in line.strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith(f"| {first}")
    ]


@pytest.mark.slow
def test_the_report_has_every_section_and_its_figures(report):
    text = report.read_text()
    for heading in ("## 1. Long runs", "## 2. Trained models", "## 3. Hard cases", "## 4. float32"):
        assert heading in text
    assert (report.parent / "S" / "long_runs.png").stat().st_size > 10_000
    assert (report.parent / "S" / "trained.png").stat().st_size > 10_000
    hard = {r[0]: r[1] for r in _rows(text, "two-body") + _rows(text, "van der Pol")}
    assert hard["two-body, tangential speed 0 × circular"] == "step_underflow"
    assert hard["two-body, tangential speed 0.001 × circular"] == "ok"
    assert hard["van der Pol μ = 1000, t ∈ [0, 3000], dopri5"] == "stiff"


@pytest.mark.parametrize("system", [MassSpring(), Pendulum()], ids=["spring", "pendulum"])
def test_symplectic_energy_error_is_bounded_and_rk4_drifts(system):
    """Over 5000 steps of h = 0.1: leapfrog's error has no trend (first and last tenth
    agree), rk4's grows linearly (the last tenth ≫ the first)."""
    leap = stress.long_run(system, "leapfrog", 5000)
    rk4 = stress.long_run(system, "rk4", 5000)
    assert leap["max"] < 0.02 and abs(leap["last"] / leap["first"] - 1) < 0.1
    assert rk4["last"] > 10 * rk4["first"] and rk4["slope"] > 0


def test_reversibility_of_the_symmetric_methods():
    for method, tol in (("leapfrog", 1e-13), ("implicit_midpoint", 1e-10), ("rk4", None)):
        err = stress.reversibility(MassSpring(), method, stress.F64)
        if tol is None:
            assert err > 1e-7  # not symmetric: returns only up to its error
        else:
            assert err < tol
