"""The guide's pages of shard 1 (tests/test_guide.py's ``SHARDS``): a file of their own,
so that ``--dist loadfile`` can run them beside the other shards."""

from __future__ import annotations

import pytest
from test_guide import SHARDS, run_page


@pytest.mark.slow
@pytest.mark.parametrize("page", SHARDS[1])
def test_guide_page_runs_in_a_fresh_directory(page, tmp_path):
    run_page(page, tmp_path)
