"""Shared test fixtures: where the repo's fixed inputs live."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def vectors_dir() -> Path:
    """The FSP conformance vectors (spec/vectors), from an independent encoder."""
    return REPO / "spec" / "vectors"
