"""The tiny in-process sweep shared by the benchmark tests (built once per session): the reference the
Dask tests compare against."""

from __future__ import annotations

import pytest

from bench_helpers import reproduce


@pytest.fixture(scope="session")
def tiny_sweep(tmp_path_factory):
    """(results folder, cache folder, summary) of the reference tiny sweep."""
    root = tmp_path_factory.mktemp("bench")
    out, cache = root / "results", root / "cache"
    summary = reproduce(out, cache)
    return out, cache, summary
