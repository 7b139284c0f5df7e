"""`wftool preflight`: its MSP parsing and report, and the command on the virtual FC — it
passes where the firmware fails safe, in both set-ups, and fails, naming the lines, where the
board holds the OBC's stale commands too long."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from tests.conftest import run_cli
from wftool.fc.versions import BETAFLIGHT_2025_12, BETAFLIGHT_2026_6
from wftool.verify.preflight import (
    ModeRange,
    PreflightReport,
    Snapshot,
    offset_rc,
    parse_mode_ranges,
    parse_status_ex,
)


def status_ex(boxes: int, arming: int, extra_boxes: bytes = b"") -> bytes:
    """An MSP_STATUS_EX payload as Betaflight 2025.12's msp.c writes it (29 arming flags)."""
    head = struct.pack("<HHHIBHBB", 125, 0, 0x21, boxes & 0xFFFFFFFF, 0, 5, 4, 0)
    return (
        head
        + bytes([len(extra_boxes)])
        + extra_boxes
        + bytes([29])
        + struct.pack("<IBH", arming, 0, 0)
    )


def test_status_ex_boxes_past_32_and_the_arming_flags() -> None:
    rx_loss = BETAFLIGHT_2025_12.rx_failsafe_flag
    boxes, arming, count = parse_status_ex(status_ex(0x10001, rx_loss, b"\x02"))
    assert boxes == 0x10001 | 0x2 << 32
    assert (arming, count) == (rx_loss, 29)


def test_mode_ranges_in_microseconds_unused_slots_left_out() -> None:
    payload = bytes([0, 2, 32, 48, 50, 1, 32, 48]) + bytes([0, 0, 0, 0]) * 3
    assert parse_mode_ranges(payload) == [ModeRange(0, 2, 1700, 2100), ModeRange(50, 1, 1700, 2100)]


def test_the_obc_commands_far_from_the_pilot() -> None:
    assert offset_rc((1500, 1500, 1500, 1000)) == (1800, 1800, 1800, 1150)
    assert offset_rc((1900, 1100, 1600, 2000)) == (1600, 1400, 1300, 2000)


def test_the_arm_switch_flag_is_the_last_of_each_version() -> None:
    # 2026.6 put AUTOPILOT_SW where 2025.12 had ARM_SWITCH (runtime_config.h)
    assert BETAFLIGHT_2025_12.arm_switch_flag == 1 << 28
    assert BETAFLIGHT_2026_6.arm_switch_flag == 1 << 29
    assert BETAFLIGHT_2026_6.arming_flag_names(1 << 28 | 1 << 2) == "RXLOSS+AUTOPILOT_SW"
    ready = Snapshot(0.0, (1500,) * 8, False, False, False, False, 1 << 29, 0)
    blocked = Snapshot(0.0, (1500,) * 8, False, False, False, True, 1 << 2, 1 << 2)
    assert ready.can_arm and not blocked.can_arm


def test_a_report_fails_on_any_line() -> None:
    report = PreflightReport("safety pilot")
    report.timing("a", 60.0, 100.0)
    assert report.ok
    report.timing("b", None, 100.0)
    report.timing("c", 101.0, 100.0)
    assert [(line.name, line.measured) for line in report.failed] == [
        ("b", "never"),
        ("c", "101.0 ms"),
    ]


@pytest.mark.slow
@pytest.mark.parametrize("mode", [(), ("--obc-only",)], ids=["safety-pilot", "obc-alone"])
def test_preflight_passes_on_the_virtual_fc(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str], mode: tuple[str, ...]
) -> None:
    code, out, err = run_cli(
        capsys, "preflight", "--sitl", "--arm", "--binary", str(sitl_binary), *mode
    )
    assert code == 0, out + err
    assert "the board fails safe" in out and "FAIL" not in out
    if mode:
        assert "OBC stuck (repeats its last packet): failsafe stage 2" in out
    else:
        assert "OBC stuck (repeats its last packet): pilot's sticks back" in out


@pytest.mark.slow
def test_preflight_fails_naming_the_lines_when_stale_commands_are_held(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """fsp_cmd_timeout_ms 150: the firmware holds the OBC's last command 150 ms, over the
    100 ms limit — every handover line fails, and the error names them."""
    code, out, err = run_cli(
        capsys, "preflight", "--sitl", "--binary", str(sitl_binary), "--cmd-timeout-ms", "150"
    )
    assert code == 1
    assert "the board does NOT fail safe" in out
    [error] = [line for line in err.splitlines() if line.startswith("error:")]
    assert error.startswith("error: the board does not fail safe: fsp_cmd_timeout_ms;")
    assert "OBC stuck (repeats its last packet): pilot's sticks back" in error
    assert "OBC killed (port closed): pilot's sticks back" in error
