"""Shared fixtures: a store per test (local temporary directory or memory://)."""

from __future__ import annotations

import uuid

import pytest

from catalog.store import Store


@pytest.fixture(params=["local", "memory"])
def store(request, tmp_path) -> Store:
    """A fresh empty store, local and in memory (every catalog test runs on both)."""
    if request.param == "local":
        yield Store(str(tmp_path / "root"))
        return
    url = f"memory://carlaocc-test-{uuid.uuid4().hex}"
    yield Store(url)
    import fsspec

    fs = fsspec.filesystem("memory")
    root = Store(url).root
    if fs.exists(root):
        fs.rm(root, recursive=True)
