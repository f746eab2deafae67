"""Shared fixtures."""

from __future__ import annotations

import pytest
from helpers import REPO


@pytest.fixture
def repo() -> str:
    return REPO
