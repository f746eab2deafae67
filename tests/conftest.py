"""Shared fixtures."""

from __future__ import annotations

import pytest
from helpers import REPO


@pytest.fixture
def repo() -> str:
    return REPO


@pytest.fixture(autouse=True, scope="session")
def _btrun_cache(tmp_path_factory):
    """Generated files (the demo gallery) go to a temporary cache, built once per session."""
    import os

    old = os.environ.get("BTRUN_CACHE_DIR")
    os.environ["BTRUN_CACHE_DIR"] = str(tmp_path_factory.mktemp("btrun-cache"))
    yield
    if old is None:
        os.environ.pop("BTRUN_CACHE_DIR", None)
    else:
        os.environ["BTRUN_CACHE_DIR"] = old
