"""The documentation site builds with ``mkdocs build --strict`` (every link, snippet and
docstring reference resolves), and the user's pages stay a user's: a short README, no
dates, issue numbers or citations of files that do not exist."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from test_readme import guide_pages

ROOT = Path(__file__).resolve().parent.parent

#: what belongs in the changelog and the results' records, not in the user's pages
NOT_FOR_USERS = re.compile(r"issue [0-9]|20[0-9]{2}-[0-9]{2}-[0-9]{2}|\bSPEC\b")


def test_the_site_builds_strictly(tmp_path):
    if importlib.util.find_spec("mkdocs") is None:
        pytest.fail("mkdocs is not installed: `pip install -e .[docs]` (make does)")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "-q"]
    command += ["-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")]
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    site = tmp_path / "site"
    home = (site / "index.html").read_text()
    assert "Hamiltonian Neural Networks" in home
    # the generated pages are read from the root, not copied into docs/
    fast = (site / "RESULTS_fast" / "index.html").read_text()
    assert "Per seed" in fast and "<details" in fast
    assert (site / "STABILITY" / "long_runs.png").is_file()
    api = (site / "api" / "integrate" / "index.html").read_text()
    assert "odeint" in api and "dopri5" in api  # rendered from the docstrings
    friction = (site / "friction" / "index.html").read_text()
    assert "dissipative HNN" in friction and "--8&lt;--" not in friction


def test_the_readme_is_short_and_the_pages_are_a_user_s():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 250
    for page in [ROOT / "README.md", *guide_pages(), ROOT / "docs" / "index.md"]:
        for n, line in enumerate(page.read_text().splitlines(), 1):
            assert not NOT_FOR_USERS.search(line), f"{page.name}:{n}: {line}"
