"""`configure fsp` against the patched SITL: the whole setup, or nothing; a safety pilot by
default, the OBC alone only when asked, with its failsafe spelled out."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tests.conftest import fc_settings
from wftool.errors import ParameterError
from wftool.fc.cli_session import CliSession
from wftool.fc.fsp_setup import (
    FSP_BAUD_RATES,
    ObcOnly,
    SafetyPilot,
    SerialPortConfig,
    check_baud,
    failsafe_outlook,
    fsp_planner,
    override_mask,
    parse_channel,
    parse_range,
)
from wftool.fc.modes import AuxRange
from wftool.fc.msp import FEATURE_RX_MSP, FEATURE_RX_UDP, RECEIVER_FEATURES, MspClient
from wftool.fc.params import apply_plan
from wftool.fc.plan import parse_cli_script, plan_from_assignments
from wftool.fc.versions import version_of
from wftool.sitl.process import VirtualFC

OBC_ALONE = ObcOnly("drop")


def _eeprom(fc: VirtualFC) -> bytes:
    return hashlib.sha256((fc.workdir / "eeprom.bin").read_bytes()).digest()


def _cli(fc: VirtualFC, *commands: str) -> list[str]:
    """The FC's answers to CLI `commands` (it leaves the CLI with `exit`)."""
    session = CliSession.open(fc.url)
    try:
        return [session.run(command) for command in commands]
    finally:
        session.exit()
        fc.wait_back()


def test_fsp_replacing_functions_is_reported(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(virtual_fc, parse_cli_script("serial UART2 2 115200 57600 0 115200", "s"), tmp_path)
    notes: list[str] = []
    apply_plan(
        virtual_fc, fsp_planner(uart=2, baud=2_000_000, control=OBC_ALONE), tmp_path, notes.append
    )
    assert "UART2: FSP replaces GPS on this port" in notes
    assert any("no dshot_bidir" in note for note in notes)  # SITL has no DShot


def test_one_bad_setting_leaves_the_whole_setup_unapplied(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError, match="fsp_rate_hz = 9000: out of range"):
        apply_plan(
            virtual_fc,
            fsp_planner(uart=2, baud=2_000_000, rate_hz=9000, control=OBC_ALONE),
            tmp_path,
        )
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
    report = apply_plan(
        virtual_fc, fsp_planner(uart=2, baud=2_000_000, rate_hz=1000, control=OBC_ALONE), tmp_path
    )
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
    with MspClient.open(virtual_fc.url) as msp:
        version = version_of(msp.identify())
        assert msp.features() & FEATURE_RX_MSP
    assert (config.functions, config.msp_baud) == (version.fsp_function, 2_000_000)
    opened = f"bind port {virtual_fc.port_base + 2} for UART2".encode()
    assert opened in virtual_fc.log_path.read_bytes()  # FSP opened it


def test_serial_line_round_trip() -> None:
    line = "serial UART3 66 115200 57600 0 230400"
    config = SerialPortConfig.parse(line)
    assert config.command() == line


def test_serial_update_rate_can_be_chosen(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    """The paper's MSP baseline ran a 1 kHz serial task: the setup takes the rate asked."""
    report = apply_plan(
        virtual_fc,
        fsp_planner(uart=2, baud=2_000_000, serial_update_rate_hz=1000, control=OBC_ALONE),
        tmp_path,
    )
    assert report.mismatches == []
    assert fc_settings(virtual_fc, "serial_update_rate_hz") == {"serial_update_rate_hz": "1000"}


def test_a_safety_pilot_by_default_keeps_the_radio_and_overrides_the_sticks(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    """The virtual FC's simulated radio as the receiver, the override on AUX2 (slot of its
    own), the sticks masked through the FC's map, the link never kept alive by the OBC."""
    apply_plan(virtual_fc, parse_cli_script("map TAER1234\naux 0 0 0 1700 2100 0 0", "s"), tmp_path)
    planner = fsp_planner(uart=2, baud=2_000_000, radio_feature=FEATURE_RX_UDP)
    notes: list[str] = []
    report = apply_plan(virtual_fc, planner, tmp_path, notes.append)
    after = {row.name: row.after for row in report.rows}
    assert report.mismatches == []
    assert after["msp_override_channels_mask"] == "15"
    assert after["msp_override_failsafe"] == "OFF"
    assert after["fsp_cmd_timeout_ms"] == "50"
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.features() & RECEIVER_FEATURES == FEATURE_RX_UDP
    [aux] = _cli(virtual_fc, "aux")
    used = [AuxRange.parse(line) for line in aux.splitlines() if line.startswith("aux ")]
    assert [r for r in used if r.usable] == [
        AuxRange(0, 0, 0, 1700, 2100),  # the pilot's ARM, untouched
        AuxRange(1, 50, 1, 1700, 2100),  # MSP OVERRIDE on AUX2
    ]
    assert any("MSP OVERRIDE on AUX2 1700-2100" in note for note in notes)


def test_a_safety_pilot_needs_the_radio_as_the_receiver(virtual_fc: VirtualFC, tmp_path: Path):
    eeprom = _eeprom(virtual_fc)  # a fresh SITL: the MSP receiver
    with pytest.raises(ParameterError, match="the FC's receiver is the MSP receiver"):
        apply_plan(virtual_fc, fsp_planner(uart=2, baud=2_000_000), tmp_path)
    assert _eeprom(virtual_fc) == eeprom


def test_the_override_switch_is_not_the_arm_switch(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    apply_plan(virtual_fc, parse_cli_script("aux 3 0 1 1300 2100 0 0", "s"), tmp_path)
    eeprom = _eeprom(virtual_fc)
    planner = fsp_planner(
        uart=2, baud=2_000_000, control=SafetyPilot(switch=2), radio_feature=FEATURE_RX_UDP
    )
    with pytest.raises(ParameterError, match=r"AUX2 carries ARM \(aux 3: ARM on AUX2 1300-2100"):
        apply_plan(virtual_fc, planner, tmp_path)
    assert _eeprom(virtual_fc) == eeprom


@pytest.mark.parametrize(
    ("aux", "why"),
    [
        ("aux 2 27 3 1700 2100 0 0", r"FAILSAFE on AUX4 1700-2100 \(the OBC's channel: a command "
         r"sent by accident would switch it\)"),
        ("aux 2 0 2 1300 2100 0 0", r"ARM on AUX3 1300-2100 \(the OBC's channel"),
        ("aux 2 1 2 900 1300 0 0", r"ANGLE on AUX3 900-1300 \(the OBC's channel"),
        ("aux 2 1 1 900 1300 0 0", r"ANGLE on AUX2 900-1300 \(FSP never drives it: stuck"),
        ("aux 2 28 4 1700 2100 0 0", r"AIR MODE on AUX5 1700-2100 \(FSP never drives it"),
        ("aux 2 1 0 1700 2100 0 0", r"ANGLE on AUX1 1700-2100 \(AUX1 is the ARM switch the FC "
         r"holds for the OBC\)"),
    ],
    ids=["failsafe-aux4", "arm-aux3", "mode-aux3", "mode-aux2", "mode-aux5", "mode-aux1"],
)  # fmt: skip
def test_obc_alone_refuses_modes_a_command_or_nothing_would_switch(
    virtual_fc: VirtualFC, tmp_path: Path, aux: str, why: str
) -> None:
    """ARM or FAILSAFE on a channel FSP drives, any mode on AUX3/AUX4 (the OBC's), on AUX2
    or AUX5 and up (FSP never drives them), anything but ARM on AUX1: refused, one line
    naming the range and why, the FC untouched."""
    apply_plan(virtual_fc, parse_cli_script(aux, "s"), tmp_path)
    eeprom = _eeprom(virtual_fc)
    with pytest.raises(ParameterError, match=f"with the OBC alone no mode may sit .*{why}") as err:
        apply_plan(virtual_fc, fsp_planner(uart=2, baud=2_000_000, control=OBC_ALONE), tmp_path)
    assert "\n" not in str(err.value)
    assert _eeprom(virtual_fc) == eeprom


def test_obc_alone_arms_through_aux1_which_the_fc_holds(virtual_fc: VirtualFC, tmp_path: Path):
    """ARM on AUX1 at 1700-2100 (an ARM range there moved into place, a second one cleared):
    the switch the FC holds for the OBC's arming requests (spec §14)."""
    apply_plan(
        virtual_fc, parse_cli_script("aux 4 0 0 900 1300 0 0\naux 6 0 0 1300 1500 0 0", "s"),
        tmp_path,
    )  # fmt: skip
    notes: list[str] = []
    apply_plan(
        virtual_fc, fsp_planner(uart=2, baud=2_000_000, control=OBC_ALONE), tmp_path, notes.append
    )
    [aux] = _cli(virtual_fc, "aux")
    assert _used(aux) == [AuxRange(4, 0, 0, 1700, 2100)]
    assert "aux 6: ARM on AUX1 1300-1500 cleared: ARM is AUX1 1700-2100" in notes
    assert any("arms and disarms only by an arming request" in note for note in notes)
    fresh = tmp_path / "fresh"  # an FC with no ARM range gets one in a free slot
    with VirtualFC(virtual_fc.binary, fresh, port_base=None) as other:
        apply_plan(other, fsp_planner(uart=2, baud=2_000_000, control=OBC_ALONE), tmp_path)
        [aux] = _cli(other, "aux")
    assert _used(aux) == [AuxRange(0, 0, 0, 1700, 2100)]


def _used(aux: str) -> list[AuxRange]:
    """The mode ranges in use in the FC's `aux` output."""
    ranges = [AuxRange.parse(line) for line in aux.splitlines() if line.startswith("aux ")]
    return [r for r in ranges if r.usable]


def test_obc_alone_sets_the_procedure_and_says_what_loss_means(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    apply_plan(virtual_fc, plan_from_assignments(["failsafe_delay=10"]), tmp_path)
    notes: list[str] = []
    planner = fsp_planner(uart=2, baud=2_000_000, control=ObcOnly("land"), cmd_timeout_ms=40)
    report = apply_plan(virtual_fc, planner, tmp_path, notes.append)
    after = {row.name: row.after for row in report.rows}
    assert (after["failsafe_procedure"], after["fsp_cmd_timeout_ms"]) == ("AUTO-LAND", "40")
    text = "\n".join(notes)
    assert "40 ms: RXLOSS" in text and "300 ms: sticks centred, throttle at rx_min_usec" in text
    assert "1000 ms: stage 2 (failsafe_delay): AUTO-LAND" in text
    with MspClient.open(virtual_fc.url) as msp:
        assert msp.features() & RECEIVER_FEATURES == FEATURE_RX_MSP


def test_failsafe_outlook_reads_the_settings() -> None:
    settings = {
        "failsafe_delay": "15", "failsafe_landing_time": "60", "failsafe_throttle": "1000",
        "rx_min_usec": "885",
    }  # fmt: skip
    lines = failsafe_outlook(settings, 50, "DROP")
    assert lines[1].startswith("  50 ms: RXLOSS")
    assert lines[3] == (
        "  1500 ms: stage 2 (failsafe_delay): DROP: the motors stop and the FC disarms — the "
        "aircraft falls"
    )


@pytest.mark.parametrize("on_us", [(900, 2100), (1000, 2000), (1100, 2100)])
def test_an_override_range_without_an_off_position_is_refused(on_us: tuple[int, int]) -> None:
    start, end = on_us
    off = r"off position: a switch's low end \(up to 1100 µs\) lies in it"
    with pytest.raises(ValueError, match=rf"the override range {start}-{end} has no {off}"):
        SafetyPilot(2, on_us)
    assert SafetyPilot(2, (1125, 2100)).on_us == (1125, 2100)  # 1100 itself is off there
    assert SafetyPilot(2, (1700, 2100)).on_us == (1700, 2100)


@pytest.mark.parametrize("baud", [2_000_001, 3_000_000, 1_234_567, 0, 4800])
def test_a_baud_rate_the_fc_does_not_have_is_refused_before_the_fc(baud: int) -> None:
    """Betaflight's baudRates[]: nothing else in a `serial` line; the planner is refused
    before it could ever open a session."""
    with pytest.raises(ParameterError, match=f"the FC takes no baud rate {baud} for a port"):
        fsp_planner(uart=2, baud=baud, control=OBC_ALONE)
    for rate in FSP_BAUD_RATES:
        assert check_baud(rate) == rate


def test_fsp_moves_between_uarts_and_the_old_port_gets_a_baud_serial_takes(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    """FSP at 2 Mbaud on UART2, then on UART3: UART2 loses FSP and its MSP baud returns to
    115200 (2000000 is refused there without FSP)."""
    apply_plan(virtual_fc, fsp_planner(uart=2, baud=2_000_000, control=OBC_ALONE), tmp_path)
    notes: list[str] = []
    report = apply_plan(
        virtual_fc, fsp_planner(uart=3, baud=1_500_000, control=OBC_ALONE), tmp_path, notes.append
    )
    assert report.mismatches == []
    assert "FSP moves from UART2 to UART3 (UART2's MSP baud back to 115200)" in notes
    [serial] = _cli(virtual_fc, "serial")
    ports = {c.port: c for c in map(SerialPortConfig.parse, filter(str.strip, serial.splitlines()))}
    assert (ports["UART2"].functions, ports["UART2"].msp_baud) == (0, 115200)
    with MspClient.open(virtual_fc.url) as msp:
        fsp = version_of(msp.identify()).fsp_function
    assert (ports["UART3"].functions, ports["UART3"].msp_baud) == (fsp, 1_500_000)


def test_a_safety_pilot_is_told_who_flies_and_how_to_engage_from_the_fcs_settings(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    """Before anything is applied: the pilot engages the OBC once it is ready (spec §15),
    with the FC's own pulse range and ARM switch; an override mask of more than the sticks
    goes back to the sticks, said."""
    apply_plan(
        virtual_fc,
        parse_cli_script(
            "aux 0 0 0 1700 2100 0 0\nset rx_min_usec = 900\nset rx_max_usec = 2100\n"
            "set msp_override_channels_mask = 255", "s",
        ),
        tmp_path,
    )  # fmt: skip
    notes: list[str] = []
    planner = fsp_planner(
        uart=2, baud=2_000_000, control=SafetyPilot(3, (1300, 2100)), cmd_timeout_ms=40,
        radio_feature=FEATURE_RX_UDP,
    )  # fmt: skip
    report = apply_plan(virtual_fc, planner, tmp_path, notes.append)
    text = "\n".join(notes)
    assert "who flies: the pilot" in text
    assert "within the FC's pulse range 900-2100 µs, for 500 ms without a break" in text
    assert "the pilot turns AUX3 off and on (into 1300-2100): ENGAGED" in text
    assert "no fresh command for 40 ms (fsp_cmd_timeout_ms), AUX3 goes off" in text
    assert "ARM (ARM on AUX1 1700-2100), AUX3 and every AUX channel are the pilot's" in text
    assert "msp_override_channels_mask 255 → 15: the sticks alone" in text
    assert {row.name: row.after for row in report.rows}["msp_override_channels_mask"] == "15"


def test_switch_range_and_mask_parsing() -> None:
    assert parse_channel("aux2") == 2 and parse_range("1700-2100") == (1700, 2100)
    for bad in ("AUX0", "AUX15", "CH5"):
        with pytest.raises(ValueError, match="expected AUX1-AUX14"):
            parse_channel(bad)
    for bad in ("1700", "2100-1700", "1710-2100", "800-1000"):
        with pytest.raises(ValueError):
            parse_range(bad)
    assert override_mask([0, 1, 3, 2, 4, 5, 6, 7]) == 15  # AETR1234
    assert override_mask([1, 2, 3, 0, 4, 5, 6, 7]) == 15  # TAER1234
