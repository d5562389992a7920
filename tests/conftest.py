"""Shared fixtures: a private data cache; one thread (the tests's tensors are small, and
a second thread only adds contention).

The suite runs on two pytest-xdist workers (``-n 2 --dist loadgroup``, pyproject's
``addopts``); each worker is one process with one torch thread. Tests that share an
expensive module-scoped fixture carry ``pytest.mark.xdist_group`` so that fixture is
built once, on one worker. ``slow`` tests are handed out first, so no long test starts
last while the other worker idles."""

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
