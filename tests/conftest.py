"""Shared fixtures: a private data cache and threads fixed for repeatable numbers."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _threads():
    torch.set_num_threads(2)


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("HNN_PL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
