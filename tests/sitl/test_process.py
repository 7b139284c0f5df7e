"""The virtual FC process manager, against the real SITL binary."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from wftool.errors import SitlError
from wftool.fc.msp import MspClient, RebootMode
from wftool.sitl.process import VirtualFC, uart_url


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_start_answers_msp_and_stop_leaves_no_process(sitl_binary: Path, tmp_path: Path) -> None:
    fc = VirtualFC(sitl_binary, tmp_path)
    with fc:
        assert fc._process is not None
        pid = fc._process.pid
        with MspClient.open(fc.url) as msp:
            assert msp.fc_variant() == "BTFL"
        assert (tmp_path / "eeprom.bin").exists()
    assert not fc.running
    assert not _alive(pid)
    assert b"bind port 5761 for UART1" in fc.log_path.read_bytes()


def test_stop_kills_a_process_that_ignores_sigterm(sitl_binary: Path, tmp_path: Path) -> None:
    fc = VirtualFC(sitl_binary, tmp_path)
    fc.start()
    assert fc._process is not None
    pid = fc._process.pid
    os.kill(pid, signal.SIGSTOP)  # a stopped process cannot act on SIGTERM
    fc.stop(grace=0.5)
    assert not _alive(pid)


def test_wait_back_restarts_after_a_firmware_reset(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        msp.reboot(RebootMode.FIRMWARE)
    virtual_fc.wait_back()
    assert virtual_fc.starts == 2
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.api_version().major == 1
    assert b"[system]Reset!" in virtual_fc.log_path.read_bytes()


def test_second_sitl_in_the_same_namespace_is_refused(
    virtual_fc: VirtualFC, sitl_binary: Path, tmp_path: Path
) -> None:
    with pytest.raises(SitlError, match="another SITL"), VirtualFC(sitl_binary, tmp_path / "b"):
        pass


def test_missing_binary_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(SitlError, match="cannot run SITL binary"):
        VirtualFC(tmp_path / "nope", tmp_path).start()


def test_uart_urls_follow_the_sitl_port_scheme() -> None:
    assert uart_url(1) == "socket://127.0.0.1:5761"
    assert VirtualFC.uart_url(2) == "socket://127.0.0.1:5762"
