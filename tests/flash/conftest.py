"""Fixtures for flashing: a real built hex, and the dfu-util stand-in on PATH."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from tests.flash.standin import FLASH_SIZE, SCRIPT, UNTOUCHED, StandinDfuUtil


@pytest.fixture(scope="session")
def built_hex() -> Path:
    """A Betaflight STM32F7X2 hex from a real build (WFTOOL_TEST_HEX), or skip."""
    path = os.environ.get("WFTOOL_TEST_HEX")
    if not path:
        pytest.skip("WFTOOL_TEST_HEX is not set (path to a built betaflight_*_STM32F7X2.hex)")
    return Path(path)


@pytest.fixture
def standin_dfu_util(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> StandinDfuUtil:
    """Put the dfu-util STAND-IN (tests/flash/standin_dfu_util.py) first on PATH."""
    bin_dir = tmp_path / "standin-bin"
    bin_dir.mkdir()
    executable = bin_dir / "dfu-util"
    executable.write_text(
        f"#!{sys.executable}\nimport runpy\nrunpy.run_path({str(SCRIPT)!r}, run_name='__main__')\n"
    )
    executable.chmod(0o755)
    state = tmp_path / "standin-state"
    state.mkdir()
    (state / "flash.bin").write_bytes(bytes([UNTOUCHED]) * FLASH_SIZE)
    monkeypatch.setenv("DFU_STANDIN_STATE", str(state))
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    standin = StandinDfuUtil(state)
    standin.configure()
    return standin
