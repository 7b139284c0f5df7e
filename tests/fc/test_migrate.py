"""Migrating a backup across Betaflight versions: what each rule rewrites, drops and says, and
what it refuses, naming the line (the real restores: tests/test_compat.py)."""

from __future__ import annotations

import pytest

from wftool.errors import ParameterError, UsageError
from wftool.fc.migrate import migrate
from wftool.fc.plan import parse_cli_script
from wftool.fc.versions import BETAFLIGHT_2025_12, BETAFLIGHT_2026_6


def dump(release: str, body: str) -> str:
    """A `diff all` as `printConfig` starts it, written by RELEASE."""
    return (
        "# version\n"
        f"# Betaflight / SITL (SITL) {release} Jan  1 2026 / 00:00:00 (abcdef012) MSP API: 1.47\n"
        "\n# start the command batch\nbatch start\n"
        "\n# reset configuration to default settings\ndefaults nosave\n" + body + "\nsave\n"
    )


OLD_BACKUP = dump(
    "2025.12.5",
    "serial UART1 1 115200 57600 0 115200\n"
    "serial UART2 524288 2000000 57600 0 115200\n"
    "serial UART3 524354 115200 57600 0 115200\n"
    "set vbat_min_cell_voltage = 330\n"
    "set gps_rescue_max_angle = 40\n"
    "set fsp_rate_hz = 1000\n"
    "profile 0\nset p_pitch = 50\n",
)


def test_a_2025_12_backup_onto_2026_6_says_each_change() -> None:
    plan = parse_cli_script(OLD_BACKUP, "b.txt")
    assert plan.written_by is not None and plan.written_by.origin == "b.txt:2"
    migration = migrate(plan, BETAFLIGHT_2026_6)
    texts = [command.text for command in migration.plan.commands]
    assert texts == [
        "defaults nosave",
        "serial UART1 1 115200 57600 0 115200",
        "serial UART2 1073741824 2000000 57600 0 115200",
        "serial UART3 1073741890 115200 57600 0 115200",  # GPS + RX_SERIAL kept, FSP moved
        "set vbat_min_cell_voltage = 330",
        "set fsp_rate_hz = 1000",
        "profile 0",
        "set p_pitch = 50",
    ]
    assert migration.changes == [
        "b.txt:2: written by Betaflight 2025.12.5; migrated onto Betaflight 2026.6:",
        "  b.txt:10: `serial UART2 524288 2000000 57600 0 115200` → "
        "`serial UART2 1073741824 2000000 57600 0 115200` (FSP is 1 << 30 on Betaflight 2026.6)",
        "  b.txt:11: `serial UART3 524354 115200 57600 0 115200` → "
        "`serial UART3 1073741890 115200 57600 0 115200` (FSP is 1 << 30 on Betaflight 2026.6)",
        "  b.txt:13: `set gps_rescue_max_angle = 40` dropped: Betaflight 2026.6 removed it — "
        "GPS rescue reworked upstream (#15382)",
        "  b.txt:12: vbat_min_cell_voltage: per battery profile on Betaflight 2026.6, set for "
        "the selected battery profile (the first, after `defaults nosave`)",
    ]


def test_the_same_version_is_left_alone() -> None:
    plan = parse_cli_script(OLD_BACKUP, "b.txt")
    migration = migrate(plan, BETAFLIGHT_2025_12)
    assert migration.plan is plan and migration.changes == []


def test_a_script_without_a_version_line_is_taken_as_written() -> None:
    plan = parse_cli_script("serial UART2 524288 2000000 57600 0 115200\n", "s.txt")
    assert plan.written_by is None
    assert migrate(plan, BETAFLIGHT_2026_6).plan is plan


def test_a_2026_6_backup_with_battery_profiles_parses_and_stays() -> None:
    text = dump(
        "2026.6.1",
        "serial UART2 1073741824 2000000 57600 0 115200\nwaypoint clear\n"
        "battery_profile 0\nset vbat_min_cell_voltage = 330\n"
        "# restore original battery_profile selection\nbattery_profile 0\n",
    )
    plan = parse_cli_script(text, "new.txt")
    assert plan.written_by is not None and plan.written_by.version is BETAFLIGHT_2026_6
    assert migrate(plan, BETAFLIGHT_2026_6).plan is plan


def test_a_newer_backup_onto_an_older_fc_is_refused_naming_the_version_line() -> None:
    plan = parse_cli_script(dump("2026.6.1", "battery_profile 1\n"), "new.txt")
    with pytest.raises(ParameterError, match=r"^new.txt:2: written by Betaflight 2026.6.1, and"):
        migrate(plan, BETAFLIGHT_2025_12)


def test_a_function_the_new_version_lacks_is_refused_naming_the_line() -> None:
    plan = parse_cli_script(dump("2025.12.5", "serial UART4 256 115200 57600 0 115200\n"), "b")
    with pytest.raises(
        ParameterError,
        match=r"b:9: `serial UART4 256 .*`: Betaflight 2026.6 has no serial function bit 8",
    ):
        migrate(plan, BETAFLIGHT_2026_6)


def test_a_script_by_a_version_wftool_does_not_know_is_refused() -> None:
    with pytest.raises(UsageError, match=r"^x.txt:2: written by Betaflight 2026.12.0, which"):
        parse_cli_script(dump("2026.12.0", "set a = 1\n"), "x.txt")


def test_a_2025_12_script_has_no_battery_profiles() -> None:
    with pytest.raises(UsageError, match="b:9: `battery_profile` is not a configuration command"):
        parse_cli_script(dump("2025.12.5", "battery_profile 0\n"), "b")
