"""Fixtures for flashing: a real built hex, and the dfu-util stand-in on PATH."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from tests.flash.standin import FLASH_SIZE, SCRIPT, UNTOUCHED, StandinDfuUtil


@pytest.fixture(scope="session")
def built_hex(request: pytest.FixtureRequest) -> Path:
    """The SPEEDYBEEF7V3 hex of this session's build (or WFTOOL_TEST_HEX): a real image."""
    path = os.environ.get("WFTOOL_TEST_HEX")
    if path:
        return Path(path)
    return request.getfixturevalue("board_build").firmware


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
