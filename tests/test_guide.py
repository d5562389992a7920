"""Every code block of the guide runs (the README's: tests/test_readme.py, whose helpers
these are): each page's blocks in order in a fresh directory, as a reader pastes them."""

from __future__ import annotations

import pytest
from test_readme import ROOT, RUNNABLE, blocks, guide_pages, run_blocks


@pytest.mark.slow
@pytest.mark.parametrize(
    "page",
    [p.name for p in guide_pages() if any(lang in RUNNABLE for lang, _ in blocks(p))],
)
def test_guide_page_runs_in_a_fresh_directory(page, tmp_path):
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    run_blocks(ROOT / "docs" / page, tmp_path)
