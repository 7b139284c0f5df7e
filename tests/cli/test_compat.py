"""A board still on the previous pin (2025.12.5 and its series) keeps working with this wftool,
and its backup restores onto a virtual FC of the current pin, migrated and said so.

Both FCs are real SITL builds: the previous pin's built once per session in a clone of its
own (`previous_sitl`; the session's own build while HEAD still pins it), the current one
`sitl_binary`. What each firmware is comes from the FC itself (MSP, its CLI), never from the
backup wftool wrote; that the restored FC streams FSP on the UART the backup gave FSP is the
proof the serial line was carried over.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.conftest import PREVIOUS_PIN, fc_settings, run_cli
from wftool.cli import fc as fc_commands
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.fc.versions import BetaflightVersion, version_of
from wftool.fsp.schedule import DEFAULT_RATE_HZ
from wftool.sitl.process import VirtualFC

pytestmark = pytest.mark.slow

FSP_UART = 2
BATTERY = ("vbat_min_cell_voltage", "341")
"""Global on 2025.12, per battery profile from 2026.6."""
GONE = ("abs_control_gain", "5")
"""A PID-profile setting of 2025.12 that 2026.6 removed."""


def firmware(fc: VirtualFC) -> BetaflightVersion:
    with MspClient.open(fc.url) as msp:
        return version_of(msp.identify())


def serial_line(fc: VirtualFC, uart: int) -> list[str]:
    """The FC's own `serial` line for UART`uart`, split (it leaves the CLI with `exit`)."""
    session = CliSession.open(fc.url)
    try:
        lines = session.run("serial").splitlines()
    finally:
        session.exit()
        fc.wait_back()
    return next(line.split() for line in lines if line.startswith(f"serial UART{uart} "))


def verify(capsys: pytest.CaptureFixture[str], fc: VirtualFC) -> dict:
    """`verify --stream --uplink` on the FC's FSP UART, judged as a board is."""
    code, out, err = run_cli(
        capsys, "verify", "--stream", "--port", fc.uart_url(FSP_UART), "--duration", "5",
        "--uplink", "--fsp-rate", str(DEFAULT_RATE_HZ), "--fc", fc.url, "--json",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads(out)
    assert summary["verdict"]["passed"] and summary["frames"] > 0
    assert summary["uplink"]["steps_echoed"] > 0
    return summary


def test_a_board_on_the_previous_pin_works_and_its_backup_restores_onto_the_pin(
    previous_sitl: Path,
    sitl_binary: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    backups = ("--backup-dir", str(tmp_path / "backups"))
    with VirtualFC(previous_sitl, tmp_path / "old", port_base=None) as old:
        monkeypatch.setattr(fc_commands, "find_board", lambda port, present=True: old)
        assert firmware(old) is PREVIOUS_PIN
        code, out, err = run_cli(capsys, "info")
        assert code == 0, err
        assert out.startswith(f"BTFL {PREVIOUS_PIN.release} (MSP API 1.47)")
        assert f"wftool talks to it as {PREVIOUS_PIN.name}" in out

        code, out, err = run_cli(
            capsys, "configure", "fsp", "--uart", str(FSP_UART), "--baud", "2000000",
            "--obc-only", "--failsafe-procedure", "drop", *backups,
        )  # fmt: skip
        assert code == 0, err
        fields = serial_line(old, FSP_UART)
        assert int(fields[2]) == PREVIOUS_PIN.fsp_function  # the old firmware's own numbering
        code, _, err = run_cli(capsys, "set", "=".join(BATTERY), "=".join(GONE), *backups)
        assert code == 0, err
        verify(capsys, old)

        code, out, err = run_cli(capsys, "backup", *backups)
        assert code == 0, err
        backup = Path(out.strip())
        assert f" {PREVIOUS_PIN.release} " in backup.read_text().splitlines()[3]

    with VirtualFC(sitl_binary, tmp_path / "new", port_base=None) as new:
        monkeypatch.setattr(fc_commands, "find_board", lambda port, present=True: new)
        current = firmware(new)
        code, out, err = run_cli(capsys, "restore", str(backup), *backups)
        assert code == 0, err
        moved = current.fsp_function != PREVIOUS_PIN.fsp_function
        if current is PREVIOUS_PIN:  # the pin has not moved yet: a backup of its own version
            assert "migrated" not in err
        else:
            assert f"written by Betaflight {PREVIOUS_PIN.release}; migrated onto" in err
            assert f"{GONE[0]} = {GONE[1]}` dropped: {current.name} removed it" in err
            assert f"{BATTERY[0]}: per battery profile on {current.name}" in err
        assert (f"FSP is 1 << {current.fsp_function.bit_length() - 1}" in err) == moved
        # the FC itself: FSP on the UART the backup gave it, at its baud, the settings kept
        assert serial_line(new, FSP_UART)[2:4] == [str(current.fsp_function), "2000000"]
        assert fc_settings(new, BATTERY[0]) == {BATTERY[0]: BATTERY[1]}
        verify(capsys, new)


def test_preflight_on_the_previous_pin(
    previous_sitl: Path, sitl_binary: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The OBC alone, armed: its arming flags are the previous version's (ARM_SWITCH moved
    from bit 28 to 29 in 2026.6)."""
    if previous_sitl == sitl_binary:
        pytest.skip("the previous pin is still the pin: tests/cli/test_preflight.py runs it")
    code, out, err = run_cli(
        capsys, "preflight", "--sitl", "--arm", "--obc-only", "--binary", str(previous_sitl)
    )
    assert code == 0, out + err
    [verdict] = [line for line in out.splitlines() if " lines passed" in line]
    assert "failed" not in verdict and "FAIL" not in out, verdict
