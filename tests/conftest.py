"""Shared fixtures: a private data cache; one thread (the tests's tensors are small, and
a second thread only adds contention)."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("HNN_PL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
