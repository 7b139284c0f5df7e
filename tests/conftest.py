"""Shared fixtures: the repo's fixed inputs and the virtual flight controller (SITL).

Run SITL tests in a private network namespace (SITL binds fixed ports):
    unshare -n sh -c 'ip link set lo up && .venv/bin/pytest'
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from wftool.sitl import VirtualFC

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def vectors_dir() -> Path:
    """The FSP conformance vectors (spec/vectors), from an independent encoder."""
    return REPO / "spec" / "vectors"


@pytest.fixture(scope="session")
def sitl_binary() -> Path:
    """The SITL binary from WFTOOL_SITL_BINARY; tests needing it skip without it."""
    path = os.environ.get("WFTOOL_SITL_BINARY")
    if not path:
        pytest.skip("WFTOOL_SITL_BINARY is not set (path to a betaflight_SITL binary)")
    return Path(path)


@pytest.fixture
def virtual_fc(sitl_binary: Path, tmp_path: Path) -> Iterator[VirtualFC]:
    """A freshly started SITL with an empty configuration, stopped after the test."""
    with VirtualFC(sitl_binary, tmp_path / "sitl") as fc:
        yield fc
