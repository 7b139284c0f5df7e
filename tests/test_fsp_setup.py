"""`configure fsp` against SITL.

The FSP settings exist only in the patched firmware (being written in parallel), so these
tests look at the SITL they are given: stock Betaflight must refuse the whole setup and
change nothing; the patched one must end up fully configured.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from wftool.cli_session import CliSession
from wftool.errors import CliCommandError, ParameterError
from wftool.fsp_setup import FSP_FUNCTION, SerialPortConfig, fsp_planner, function_names
from wftool.msp import FEATURE_RX_MSP, MspClient
from wftool.params import apply_plan, parse_cli_script, plan_from_assignments
from wftool.sitl import VirtualFC


def _has_fsp(fc: VirtualFC) -> bool:
    session = CliSession.open(fc.url)
    try:
        session.get("fsp_rate_hz")
        return True
    except CliCommandError:
        return False
    finally:
        session.exit()
        fc.wait_back()


@pytest.fixture
def stock_fc(virtual_fc: VirtualFC) -> VirtualFC:
    if _has_fsp(virtual_fc):
        pytest.skip("this SITL has the FSP settings (patched firmware)")
    return virtual_fc


@pytest.fixture
def patched_fc(virtual_fc: VirtualFC) -> VirtualFC:
    if not _has_fsp(virtual_fc):
        pytest.skip("this SITL lacks the FSP settings (`get fsp_rate_hz`): stock firmware")
    return virtual_fc


def _eeprom(fc: VirtualFC) -> bytes:
    return hashlib.sha256((fc.workdir / "eeprom.bin").read_bytes()).digest()


def test_stock_firmware_refuses_fsp_and_nothing_changes(
    stock_fc: VirtualFC, tmp_path: Path
) -> None:
    eeprom = _eeprom(stock_fc)
    with pytest.raises(ParameterError) as error:
        apply_plan(stock_fc, fsp_planner(uart=2, baud=921600), tmp_path)
    text = str(error.value)
    for name in ("fsp_rate_hz", "acc_rpm_filter_harmonics", "acc_rpm_filter_q"):
        assert f"{name}: the FC says INVALID NAME: {name}" in text
    assert _eeprom(stock_fc) == eeprom
    session = CliSession.open(stock_fc.url)
    try:
        assert "serial UART2 0 " in session.run("serial")
    finally:
        session.exit()


def test_fsp_replacing_functions_is_reported(stock_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(stock_fc, parse_cli_script("serial UART2 2 115200 57600 0 115200", "s"), tmp_path)
    notes: list[str] = []
    with pytest.raises(ParameterError):  # stock firmware: refused after planning
        apply_plan(stock_fc, fsp_planner(uart=2, baud=921600), tmp_path, notes.append)
    assert "UART2: FSP replaces GPS on this port" in notes
    assert any("no dshot_bidir" in note for note in notes)  # SITL has no DShot


def test_fsp_cannot_take_the_only_msp_port(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError, match="UART1 is the FC's only MSP port"):
        apply_plan(virtual_fc, fsp_planner(uart=1, baud=921600), tmp_path)
    with pytest.raises(ParameterError, match=r"the FC has no UART9 \(it has UART1, UART2"):
        apply_plan(virtual_fc, fsp_planner(uart=9, baud=921600), tmp_path)
    assert _eeprom(virtual_fc) == eeprom


def test_patched_firmware_gets_fully_configured(patched_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(patched_fc, plan_from_assignments(["acc_rpm_filter_harmonics=2"]), tmp_path)
    report = apply_plan(patched_fc, fsp_planner(uart=2, baud=921600, rate_hz=1000), tmp_path)
    after = {row.name: row.after for row in report.rows}
    assert after["fsp_rate_hz"] == "1000"
    assert after["acc_rpm_filter_harmonics"] == "1"  # back to the default the setup asks for
    assert after["acc_rpm_filter_q"] == "500"
    assert report.mismatches == []
    session = CliSession.open(patched_fc.url)
    try:
        uart2 = next(line for line in session.run("serial").splitlines() if " UART2 " in line)
        limit = session.get("serial_update_rate_hz")
        assert limit.int_range is not None and limit.value == str(limit.int_range[1])
    finally:
        session.exit()
        patched_fc.wait_back()
    config = SerialPortConfig.parse(uart2)
    assert (config.functions, config.msp_baud) == (FSP_FUNCTION, 921600)
    with MspClient.open(patched_fc.url) as msp:
        assert msp.features() & FEATURE_RX_MSP
    assert b"bind port 5762 for UART2" in patched_fc.log_path.read_bytes()  # FSP opened it


def test_serial_line_round_trip_and_function_names() -> None:
    line = "serial UART3 66 115200 57600 0 230400"
    config = SerialPortConfig.parse(line)
    assert config.command() == line
    assert function_names(66) == "GPS+RX_SERIAL"
    assert function_names(FSP_FUNCTION | 1 << 30) == "FSP+bit 30"
