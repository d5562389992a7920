"""Every code block of the guide runs (the README's: tests/test_readme.py, whose helpers
these are): each page's blocks in order in a fresh directory, as a reader pastes them.

The pages are split over three files (this one, test_guide_1.py, test_guide_2.py), one
shard each: ``--dist loadfile`` runs a file's tests on one worker, and the pages
together take about 3½ minutes, so in one file they would set the ``slow`` tier's wall
time alone. :data:`SHARDS` places each runnable page (about a minute of pages each)."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_readme import ROOT, RUNNABLE, blocks, guide_pages, run_blocks

#: the runnable pages of each file (test_guide.py, test_guide_1.py, test_guide_2.py)
SHARDS = (
    ("cli.md",),
    ("chain_pendulum.md", "recordings.md", "design.md", "priors.md"),
    ("positions.md", "bumps.md", "friction.md"),
)


def runnable_pages() -> list[str]:
    """The guide's pages with a block to run, in the nav's order."""
    return [p.name for p in guide_pages() if any(lang in RUNNABLE for lang, _ in blocks(p))]


def run_page(page: str, tmp_path: Path) -> None:
    """``docs/PAGE``'s blocks in ``tmp_path``, with the repository's ``examples/`` there."""
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    run_blocks(ROOT / "docs" / page, tmp_path)


def test_every_runnable_page_is_in_one_shard():
    placed = [page for shard in SHARDS for page in shard]
    assert sorted(placed) == sorted(runnable_pages()), "place each page in one of SHARDS"


@pytest.mark.slow
@pytest.mark.parametrize("page", SHARDS[0])
def test_guide_page_runs_in_a_fresh_directory(page, tmp_path):
    run_page(page, tmp_path)
