"""`configure fsp` against the patched SITL: the whole setup, or nothing."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tests.conftest import fc_settings
from wftool.errors import ParameterError
from wftool.fc.cli_session import CliSession
from wftool.fc.fsp_setup import FSP_FUNCTION, SerialPortConfig, fsp_planner, function_names
from wftool.fc.msp import FEATURE_RX_MSP, MspClient
from wftool.fc.params import apply_plan, parse_cli_script, plan_from_assignments
from wftool.sitl.process import VirtualFC


def _eeprom(fc: VirtualFC) -> bytes:
    return hashlib.sha256((fc.workdir / "eeprom.bin").read_bytes()).digest()


def test_fsp_replacing_functions_is_reported(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(virtual_fc, parse_cli_script("serial UART2 2 115200 57600 0 115200", "s"), tmp_path)
    notes: list[str] = []
    apply_plan(virtual_fc, fsp_planner(uart=2, baud=2_000_000), tmp_path, notes.append)
    assert "UART2: FSP replaces GPS on this port" in notes
    assert any("no dshot_bidir" in note for note in notes)  # SITL has no DShot


def test_one_bad_setting_leaves_the_whole_setup_unapplied(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError, match="fsp_rate_hz = 9000: out of range"):
        apply_plan(virtual_fc, fsp_planner(uart=2, baud=2_000_000, rate_hz=9000), tmp_path)
    assert _eeprom(virtual_fc) == eeprom
    session = CliSession.open(virtual_fc.url)
    try:
        assert "serial UART2 0 " in session.run("serial")
    finally:
        session.exit()


def test_fsp_cannot_take_the_only_msp_port(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError, match="UART1 is the FC's only MSP port"):
        apply_plan(virtual_fc, fsp_planner(uart=1, baud=921600), tmp_path)
    with pytest.raises(ParameterError, match=r"the FC has no UART9 \(it has UART1, UART2"):
        apply_plan(virtual_fc, fsp_planner(uart=9, baud=921600), tmp_path)
    assert _eeprom(virtual_fc) == eeprom


def test_patched_firmware_gets_fully_configured(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(virtual_fc, plan_from_assignments(["acc_rpm_filter_harmonics=2"]), tmp_path)
    report = apply_plan(virtual_fc, fsp_planner(uart=2, baud=2_000_000, rate_hz=1000), tmp_path)
    after = {row.name: row.after for row in report.rows}
    assert after["fsp_rate_hz"] == "1000"
    assert after["acc_rpm_filter_harmonics"] == "1"  # back to the default the setup asks for
    assert after["acc_rpm_filter_q"] == "500"
    assert report.mismatches == []
    session = CliSession.open(virtual_fc.url)
    try:
        uart2 = next(line for line in session.run("serial").splitlines() if " UART2 " in line)
        limit = session.get("serial_update_rate_hz")
        assert limit.int_range is not None and limit.value == str(limit.int_range[1])
    finally:
        session.exit()
        virtual_fc.wait_back()
    config = SerialPortConfig.parse(uart2)
    assert (config.functions, config.msp_baud) == (FSP_FUNCTION, 2_000_000)
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.features() & FEATURE_RX_MSP
    opened = f"bind port {virtual_fc.port_base + 2} for UART2".encode()
    assert opened in virtual_fc.log_path.read_bytes()  # FSP opened it


def test_serial_line_round_trip_and_function_names() -> None:
    line = "serial UART3 66 115200 57600 0 230400"
    config = SerialPortConfig.parse(line)
    assert config.command() == line
    assert function_names(66) == "GPS+RX_SERIAL"
    assert function_names(FSP_FUNCTION | 1 << 30) == "FSP+bit 30"


def test_serial_update_rate_can_be_chosen(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    """The paper's MSP baseline ran a 1 kHz serial task: the setup takes the rate asked."""
    report = apply_plan(
        virtual_fc, fsp_planner(uart=2, baud=2_000_000, serial_update_rate_hz=1000), tmp_path
    )
    assert report.mismatches == []
    assert fc_settings(virtual_fc, "serial_update_rate_hz") == {"serial_update_rate_hz": "1000"}
