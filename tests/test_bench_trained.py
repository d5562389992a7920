"""Smoke test of the ``benchmarks/`` topics that train and score models before they
measure (tests/test_bench.py's :data:`~test_bench.TRAINED`, about 70 s with
``--quick``): each writes its section with its tables. ``slow``: the report's
structure and hand-written text are tested on the other topics in the default tier."""

from __future__ import annotations

import pytest
from test_bench import TRAINED, has_headers, quick_report, section_bodies, tables


@pytest.mark.slow
def test_trained_topics_write_their_sections_and_tables(tmp_path, data_cache):
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# hnn_pl benchmarks\n\nHand-written introduction.\n")
    report = quick_report(out, TRAINED, data_cache)
    assert report.startswith("# hnn_pl benchmarks\n\nHand-written introduction.\n")
    bodies = section_bodies(report, ("machine", *TRAINED))
    assert all(tables(body) for body in bodies.values())  # every section has a table
    has_headers(
        report, ("learned-H drift", "beating every dopri5 setting", "reference code's best")
    )
    has_headers(report, ("HNN trained on", "the recording's slope", "step ÷ (calls × call)"))
