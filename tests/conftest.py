"""Shared fixtures: a private data cache; one thread (the tests's tensors are small, and
a second thread only adds contention).

Two tiers: ``make test`` runs ``-m "not slow"`` (every unit and the short end-to-end
runs), ``make test-all`` everything; a test is marked ``slow`` when it is an end-to-end
run (a README or guide page as written, a training run judged on its result, a built
wheel) that no quicker test can stand in for.

The suite runs on two pytest-xdist workers (``-n 2 --dist loadfile``, pyproject's
``addopts``), each one process with one torch thread. A file's tests run on one worker,
so a module-scoped fixture (a fit, a report) is built once. Files are handed out in
collection order, the files of ``slow`` tests first, so no long test starts last while
the other worker idles. (``--dist loadgroup`` and ``xdist_group`` marks do not group
under pytest 9.2 with pytest-xdist 3.8.0: the group suffix xdist writes to
``item._nodeid`` is not the node id pytest 9.2 reads.)"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable


@pytest.fixture(autouse=True, scope="session")
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def data_cache(tmp_path_factory) -> Path:
    """The run's data cache, one for all xdist workers (writes are atomic renames), so a
    task's data is generated once per run rather than once per worker."""
    base = tmp_path_factory.getbasetemp()
    return (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "cache"


@pytest.fixture(autouse=True)
def _cache(data_cache, monkeypatch):
    monkeypatch.setenv("HNN_PL_CACHE", str(data_cache))
    # seed_everything exports PL_GLOBAL_SEED, which a DataModule's seed=None follows:
    # restored after each test, so no test's seed becomes another's default
    monkeypatch.delenv("PL_GLOBAL_SEED", raising=False)
