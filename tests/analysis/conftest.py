"""Fixtures for the analysis tests: the patched tree, the compiled harness, the M7 image.

The tree is the one the run's firmware was built from (`firmware_tree`, tests/conftest.py),
patched by the same code `wftool analyze accfilter` uses; compiling needs gcc, the M7 image
needs the ARM toolchain and Unicorn. Each fixture skips, with the reason, only when that is absent.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def filter_tree(firmware_tree: Path) -> Path:
    """betaflight/ of the fresh clone, holding the patch series."""
    from wftool.analysis.sources import patched_tree

    return patched_tree(firmware_tree.parent)


@pytest.fixture(scope="session")
def filter_sources(filter_tree: Path, tmp_path_factory: pytest.TempPathFactory):
    from wftool.analysis.sources import filter_sources

    return filter_sources(filter_tree, tmp_path_factory.mktemp("sources"))


@pytest.fixture(scope="session")
def host_harness(filter_sources, tmp_path_factory: pytest.TempPathFactory):
    """The harness compiled from the tree's filter code with the host gcc."""
    pytest.importorskip("numpy", reason="needs the analysis extra (NumPy)")
    if shutil.which("gcc") is None:
        pytest.skip("no host gcc to compile the filter harness")
    from wftool.analysis.harness import HostHarness, compile_host_library

    return HostHarness(compile_host_library(filter_sources, tmp_path_factory.mktemp("host")))


@pytest.fixture(scope="session")
def m7_image(firmware_tree: Path, filter_sources, tmp_path_factory: pytest.TempPathFactory):
    """The harness and filter built for the Cortex-M7 with Betaflight's F7 flags."""
    from wftool.analysis.m7 import build_image
    from wftool.analysis.sources import arm_gcc
    from wftool.errors import ToolchainError

    try:
        gcc = arm_gcc(firmware_tree.parent)
    except ToolchainError as exc:
        pytest.skip(f"no ARM toolchain: {exc}")
    return build_image(filter_sources, tmp_path_factory.mktemp("m7"), gcc)


@pytest.fixture
def m7(m7_image):
    pytest.importorskip("unicorn", reason="needs the analysis extra (Unicorn)")
    from wftool.analysis.m7 import M7Harness

    return M7Harness(m7_image)
