"""The click layer: one-line errors and exit codes, and the happy paths against SITL.

`find_board` (how the CLI locates a USB FC) is pointed at the virtual FC; everything
below it is the real code path.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import run_cli as run
from wftool.cli import fc as fc_commands
from wftool.sitl.process import VirtualFC


@pytest.fixture
def on_sitl(virtual_fc: VirtualFC, monkeypatch: pytest.MonkeyPatch) -> VirtualFC:
    monkeypatch.setattr(fc_commands, "find_board", lambda port, present=True: virtual_fc)
    return virtual_fc


def test_bad_assignment_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz")
    assert code == 2
    assert err == "error: expected NAME=VALUE, got 'gyro_lpf1_static_hz'\n"


def test_unopenable_port_is_a_port_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "info", "--port", "/dev/wftool-no-such-tty")
    assert code == 2
    assert err.startswith("error: cannot open /dev/wftool-no-such-tty: ")
    assert err.count("\n") == 1


def test_unknown_script_command_is_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    script = tmp_path / "x.txt"
    script.write_text("set a = 1\nflash_erase\n")
    code, _, err = run(capsys, "config", "apply", str(script))
    assert (code, err) == (2, "error: x.txt:2: `flash_erase` is not a configuration command "
                              "wftool replays (nothing was changed)\n")  # fmt: skip


def test_invalid_parameter_exits_2_with_the_fcs_reason(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, _, err = run(
        capsys,
        "set",
        "no_such_setting=1",
        "gyro_lpf1_static_hz=5000",
        "--backup-dir",
        str(tmp_path),
    )
    assert code == 2
    *progress, error = err.splitlines()
    assert error.startswith(
        "error: 2 invalid, nothing changed: no_such_setting: the FC says INVALID"
    )
    assert "gyro_lpf1_static_hz = 5000: out of range; Allowed range: 0 - 1000" in error
    assert progress[0].startswith("wftool: backup of the current configuration: ")


def test_set_prints_the_before_after_table(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, _ = run(capsys, "set", "gyro_lpf1_static_hz=222", "--backup-dir", str(tmp_path))
    assert code == 0
    row = next(line for line in out.splitlines() if "gyro_lpf1_static_hz" in line)
    assert [cell.strip() for cell in row.split("│")[1:-1]] == [
        "gyro_lpf1_static_hz", "", "250", "222", "ok"
    ]  # fmt: skip


def test_backup_restore_and_info(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, _ = run(capsys, "backup", "--backup-dir", str(tmp_path))
    backup = Path(out.strip())
    assert code == 0 and backup.parent == tmp_path and "defaults nosave" in backup.read_text()
    code, out, _ = run(capsys, "restore", str(backup), "--backup-dir", str(tmp_path))
    assert code == 0 and "backup of the previous configuration" in out
    code, out, _ = run(capsys, "info")
    assert code == 0 and out.startswith("BTFL 2025.12.5 (MSP API 1.47)")


def test_configure_fsp_prints_what_it_changed(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, err = run(capsys, "configure", "fsp", "--uart", "2", "--baud", "2000000",
                         "--rate", "800", "--backup-dir", str(tmp_path))  # fmt: skip
    assert code == 0, err
    row = next(line for line in out.splitlines() if "fsp_rate_hz" in line)
    assert [cell.strip() for cell in row.split("│")[1:-1]][2:] == ["1100", "800", "ok"]
    assert "serial_update_rate_hz" in out and "features (MSP)" in out


def test_flash_without_firmware_or_fc_answer(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "flash", "--no-reboot")
    assert code == 2 and err.startswith("error: name the FIRMWARE to flash")


def test_doctor_fix_into_a_directory(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, err = run(capsys, "doctor", "--fix", "--udev-rules-dir", str(tmp_path))
    assert (tmp_path / "70-wftool.rules").exists()
    assert f"wrote {tmp_path / '70-wftool.rules'}" in err
    assert "  ok udev rules: access to 0483:df11 and 0483:5740 granted" in out
    assert code == (1 if " fail " in out else 0)
