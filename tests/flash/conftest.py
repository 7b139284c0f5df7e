"""Fixtures for flashing: a real built hex, the emulated STM32F722 bootloader that the real
dfu-util talks to (emulator.py), and the virtual board (virtual_board.py: the virtual FC
and that bootloader joined by test scaffolding)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.flash.emulator import EmulatedBootloader, unavailable
from tests.flash.images import OLD_FLASH
from tests.flash.virtual_board import VirtualBoard
from wftool.cli import fc as fc_commands
from wftool.flash import dfu
from wftool.sitl.process import VirtualFC


@pytest.fixture(scope="session")
def built_hex(request: pytest.FixtureRequest) -> Path:
    """The SPEEDYBEEF7V3 hex of this run's build (or WFTOOL_TEST_HEX): a real image."""
    path = os.environ.get("WFTOOL_TEST_HEX")
    if path:
        return Path(path)
    return request.getfixturevalue("board_firmware")


@pytest.fixture
def bootloader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[EmulatedBootloader]:
    """The emulated bootloader, not on the bus yet, its flash holding OLD_FLASH; wftool's
    dfu-util is the real one, run against it."""
    if reason := unavailable():
        pytest.skip(reason)
    with EmulatedBootloader(tmp_path / "umockdev-host.log") as emulated:
        emulated.load(OLD_FLASH)
        monkeypatch.setattr(dfu, "DFU_UTIL", emulated.dfu_util)
        yield emulated


@pytest.fixture
def virtual_board(
    sitl_binary: Path, bootloader: EmulatedBootloader, tmp_path: Path
) -> Iterator[VirtualBoard]:
    """A freshly started virtual board (empty configuration), stopped after the test."""
    fc = VirtualFC(sitl_binary, tmp_path / "sitl", port_base=None)
    with VirtualBoard(fc, bootloader) as board:
        yield board


@pytest.fixture
def on_board(virtual_board: VirtualBoard, monkeypatch: pytest.MonkeyPatch) -> VirtualBoard:
    """The virtual board as the board the CLI finds (`find_board`)."""
    monkeypatch.setattr(fc_commands, "find_board", lambda port, present=True: virtual_board)
    return virtual_board
