"""Preflight on the virtual FC configured as a board that flies: a user's backup loaded as the
virtual FC takes it (its hardware left out, its receiver the simulated radio unless the OBC
flies alone), and each broken configuration failing on its line. The backups are the
virtual FC's own, as `wftool backup` writes them after `configure fsp`."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.fc.stand_in import cli_stand_in
from wftool.errors import UsageError
from wftool.fc.cli_session import CliSession
from wftool.fc.fsp_setup import ObcOnly, SafetyPilot
from wftool.fc.msp import FEATURE_RX_UDP
from wftool.fc.params import take_backup
from wftool.fc.versions import BETAFLIGHT_2025_12, BETAFLIGHT_2026_6
from wftool.preflight.virtual import load_backup, on_virtual_fc
from wftool.sitl.session import VirtualFcSession

BOARD_LINES = """\
resource MOTOR 1 B06
timer B06 AF2
dma ADC 1 1
board_name SPEEDYBEEF7V3
set dshot_bidir = ON
feature RX_SERIAL
serial UART6 64 115200 57600 0 115200
serial UART3 524288 2000000 57600 0 115200
serial VCP 1 115200 57600 0 115200
aux 0 50 1 1700 2100 0 0
set msp_override_channels_mask = 15
"""


def sitl_cli(command: str) -> bytes:
    """A CLI that knows every setting but `dshot_bidir` (SITL has no DShot)."""
    name = command.removeprefix("get ").strip()
    if command.startswith("get ") and name == "dshot_bidir":
        return b"###ERROR IN get: INVALID NAME: dshot_bidir###"
    if command.startswith("get "):
        return f"{name} = 1\r\nAllowed range: 0 - 262143".encode()
    return b""


def test_a_boards_backup_loads_without_its_hardware(tmp_path: Path) -> None:
    path = tmp_path / "board.txt"
    path.write_text(BOARD_LINES)
    backup = load_backup(path)
    assert backup.fsp_uart == 3 and not backup.obc_alone
    with cli_stand_in(sitl_cli) as url:
        session = CliSession.open(url)
        plan = backup.planner(session, BETAFLIGHT_2025_12)  # a dump that does not say
        session.close()
    assert [c.text for c in plan.commands] == [
        "serial UART6 0 115200 57600 0 115200",  # the radio's UART: the simulated radio instead
        "serial UART3 524288 2000000 57600 0 115200",
        "aux 0 50 1 1700 2100 0 0",
        "set msp_override_channels_mask = 15",
        "set runaway_takeoff_prevention = OFF",
        "set fsp_time_reply = ON",
    ]
    assert backup.skipped == [
        "resource MOTOR 1 B06", "timer B06 AF2", "dma ADC 1 1", "board_name SPEEDYBEEF7V3",
        "set dshot_bidir", "feature RX_SERIAL", "serial VCP 1 115200 57600 0 115200",
    ]  # fmt: skip
    assert plan.features is not None and plan.features.enable == FEATURE_RX_UDP


def test_a_backup_of_a_2025_12_board_is_migrated_onto_the_virtual_fcs_version(
    tmp_path: Path,
) -> None:
    """FSP's serial function is renumbered (1 << 19 on 2025.12, 1 << 30 on 2026.6)."""
    path = tmp_path / "board.txt"
    path.write_text(
        "# version\n# Betaflight / STM32F7X2 (S7X2) 2025.12.5 Jan  1 2026 / 00:00:00 "
        "(abcdef012) MSP API: 1.47\n" + BOARD_LINES
    )
    backup = load_backup(path)
    assert backup.fsp_uart == 3
    with cli_stand_in(sitl_cli) as url:
        session = CliSession.open(url)
        plan = backup.planner(session, BETAFLIGHT_2026_6)
        session.close()
    fsp = BETAFLIGHT_2026_6.fsp_function
    assert f"serial UART3 {fsp} 2000000 57600 0 115200" in [c.text for c in plan.commands]


def test_a_backup_without_fsp_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "plain.txt"
    path.write_text("serial UART1 1 115200 57600 0 115200\nset fsp_cmd_timeout_ms = 50\n")
    with pytest.raises(UsageError, match="FSP is on no UART1-UART8"):
        load_backup(path)


@pytest.fixture(scope="module")
def backups(sitl_binary: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The virtual FC's own backups after `configure fsp` (a safety pilot; the OBC alone)."""
    texts = {}
    for name, control in (("pilot", SafetyPilot()), ("alone", ObcOnly("drop"))):
        workdir = tmp_path_factory.mktemp(name)
        with VirtualFcSession(sitl_binary, workdir, port_base=None, control=control) as fc:
            texts[name] = take_backup(fc.fc, workdir / "backups").read_text()
    return texts


def settings_failed(binary: Path, text: str, tmp_path: Path) -> dict[str, str]:
    """The failed lines of the settings of the configuration `text`: name → measured."""
    path = tmp_path / "config.txt"
    path.write_text(text)
    with on_virtual_fc(
        binary, backup=load_backup(path), port_base=None, settings_only=True, workdir=tmp_path
    ) as preflight:
        report = preflight.run()
    assert report.unchecked  # the scenarios: not checked, saying so
    return {line.name: line.measured for line in report.failed}


BROKEN = {
    "switch range without off": (
        "pilot", ("aux 0 50 1 1700 2100", "aux 0 50 1 900 2100"),
        "the override switch has an off position", "AUX2 900-2100, no off position",
    ),
    "msp_override_failsafe ON": (
        "pilot", ("set msp_override_channels_mask = 15", "set msp_override_channels_mask = 15\n"
                  "set msp_override_failsafe = ON"),
        "msp_override_failsafe OFF (the OBC never keeps a lost radio link alive)", "ON",
    ),
    "a mask with AUX channels": (
        "pilot", ("set msp_override_channels_mask = 15", "set msp_override_channels_mask = 79"),
        "msp_override_channels_mask: the sticks only", "79 (channels 1, 2, 3, 4, 7)",
    ),
    "timeout above the limit": (
        "pilot", ("set msp_override_channels_mask = 15", "set msp_override_channels_mask = 15\n"
                  "set fsp_cmd_timeout_ms = 150"),
        "fsp_cmd_timeout_ms", "150 ms",
    ),
    "ARM on an OBC channel": (
        "alone", ("serial UART2", "aux 9 0 2 1700 2100 0 0\nserial UART2"),
        "ARM on AUX1 only, the switch the FC holds (arming requests)", "ARM on AUX3 1700-2100",
    ),
    "a mode on AUX5": (
        "alone", ("serial UART2", "aux 9 1 4 1300 1700 0 0\nserial UART2"),
        "no mode on AUX1/AUX2/AUX5+ (FSP never drives them: it would be stuck)",
        "ANGLE on AUX5 1300-1700",
    ),
}  # fmt: skip
"""A broken configuration: (the backup it breaks, (a line, what it becomes), the line of
the report that fails, what that line measured)."""


@pytest.mark.parametrize("broken", list(BROKEN))
def test_a_broken_configuration_fails_naming_its_line(
    broken: str, backups: dict[str, str], sitl_binary: Path, tmp_path: Path
) -> None:
    setup, (old, new), line, culprit = BROKEN[broken]
    text = backups[setup]
    assert old in text
    failed = settings_failed(sitl_binary, text.replace(old, new, 1), tmp_path)
    assert culprit in failed.get(line, ""), failed


@pytest.mark.parametrize("setup", ["pilot", "alone"])
def test_what_configure_fsp_leaves_passes_its_settings(
    setup: str, backups: dict[str, str], sitl_binary: Path, tmp_path: Path
) -> None:
    assert settings_failed(sitl_binary, backups[setup], tmp_path) == {}
