"""The click layer: one-line errors and exit codes, and the happy paths against SITL.

`find_board` (how the CLI locates a USB FC) is pointed at the virtual FC (`on_sitl`);
everything below it is the real code path.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import answers_msp, fc_settings
from tests.conftest import run_cli as run
from tests.fc.faulty_transport import InjectFaults
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.sitl.process import VirtualFC

MSP_SET_BOARD_INFO = 248


def test_bad_assignment_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz")
    assert code == 2
    assert err == "error: expected NAME=VALUE, got 'gyro_lpf1_static_hz'\n"


def test_unopenable_port_is_a_port_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "info", "--port", "/dev/wftool-no-such-tty")
    assert code == 2
    assert err.startswith("error: cannot open /dev/wftool-no-such-tty: ")
    assert err.count("\n") == 1


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("x.txt", "set a = 1\nflash_erase\n",
         "error: x.txt:2: `flash_erase` is not a configuration command wftool replays "
         "(nothing was changed)\n"),
        ("x.toml", 'gyro_lpf1_static_hz = 200\ncraft_name = "caf\xe9"\n',
         "error: x.toml: craft_name: 'set craft_name = caf\xe9': the FC's CLI takes printable "
         "ASCII only, not '\xe9' (nothing was changed)\n"),
    ],
    ids=["unknown-command", "non-ascii-toml-value"],
)  # fmt: skip
def test_a_file_wftool_will_not_send_is_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, name: str, text: str, message: str
) -> None:
    script = tmp_path / name
    script.write_text(text)
    assert run(capsys, "config", "apply", str(script))[::2] == (2, message)


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
    assert code == 0 and out.startswith("BTFL 2026.6.1 (MSP API 1.48)")


def test_configure_fsp_prints_what_it_changed(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, err = run(capsys, "configure", "fsp", "--uart", "2", "--baud", "2000000",
                         "--rate", "800", "--obc-only", "--failsafe-procedure", "drop",
                         "--backup-dir", str(tmp_path))  # fmt: skip
    assert code == 0, err
    row = next(line for line in out.splitlines() if "fsp_rate_hz" in line)
    assert [cell.strip() for cell in row.split("│")[1:-1]][2:] == ["1100", "800", "ok"]
    assert "serial_update_rate_hz" in out and "features (MSP)" in out
    assert "50 ms: RXLOSS (fsp_cmd_timeout_ms)" in err  # what losing the OBC means
    assert "1500 ms: stage 2 (failsafe_delay): DROP" in err


def test_configure_fsp_keeps_a_safety_pilot_unless_told(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """On an FC whose receiver is the MSP receiver the default (a safety pilot) is refused in
    one line; --obc-only without its procedure is refused before the FC is touched."""
    eeprom = _eeprom(on_sitl)
    code, _, err = run(capsys, "configure", "fsp", "--uart", "2", "--baud", "2000000",
                       "--backup-dir", str(tmp_path))  # fmt: skip
    assert code == 2 and "the FC's receiver is the MSP receiver" in err and "--obc-only" in err
    assert len(err.strip().splitlines()) <= 2  # the backup note, the error
    code, _, err = run(capsys, "configure", "fsp", "--uart", "2", "--baud", "2000000",
                       "--obc-only", "--backup-dir", str(tmp_path))  # fmt: skip
    assert code == 2 and err.startswith("error: --obc-only needs --failsafe-procedure")
    assert _eeprom(on_sitl) == eeprom


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (("--override-range", "1000-2000"),
         "error: the override range 1000-2000 has no off position: a switch's low end (up to "
         "1100 µs) lies in it, so the OBC would fly with the switch off — start it above that, "
         "e.g. 1700-2100\n"),
        (("--override-range", "900-2100"), "error: the override range 900-2100 has no off"),
        (("--baud", "3000000"), "error: --baud: the FC takes no baud rate 3000000 for a port: "
         "one of 9600, 19200,"),
    ],
)  # fmt: skip
def test_configure_fsp_refuses_a_switch_without_off_or_a_baud_the_fc_lacks_before_the_fc(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, options: tuple[str, ...], message: str
) -> None:
    """One line, exit 2, and no FC touched (no port given, no backup taken)."""
    args = ("--uart", "2", "--baud", "2000000", *options, "--backup-dir", str(tmp_path / "b"))
    code, _, err = run(capsys, "configure", "fsp", *args, "--port", "/dev/wftool-no-such-tty")
    assert code == 2 and err.startswith(message) and err.count("\n") == 1
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("fields", [6, 8])
def test_a_serial_line_of_another_shape_is_refused_and_changes_nothing(
    on_sitl: VirtualFC,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    fields: int,
) -> None:
    real_run = CliSession.run

    def other_serial(self: CliSession, command: str, timeout: float | None = None) -> str:
        """The FC's own `serial` output, with its first line one field short or long."""
        output = real_run(self, command, timeout)
        if command != "serial":
            return output
        first, _, rest = output.partition("\n")
        first = first.rsplit(" ", 1)[0] if fields == 6 else f"{first} 0"
        return f"{first}\n{rest}"

    monkeypatch.setattr(CliSession, "run", other_serial)
    eeprom = _eeprom(on_sitl)
    backups = tmp_path / "backups"
    code, _, err = run(capsys, "configure", "fsp", "--uart", "2", "--baud", "2000000",
                       "--backup-dir", str(backups))  # fmt: skip
    assert code == 1, err
    last = err.splitlines()[-1]
    assert last.startswith("error: the FC's `serial` output has a line wftool does not know: ")
    assert last.endswith("— nothing was saved; the FC drops unsaved changes on reboot "
                         f"(backup: {next(backups.iterdir())})")  # fmt: skip
    assert "interrupted" not in err
    _assert_as_before(on_sitl, eeprom)


def test_flash_without_firmware_or_fc_answer(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "flash", "--no-reboot")
    assert code == 2 and err.startswith("error: name the FIRMWARE to flash")


def test_doctor_fix_into_a_directory(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, err = run(capsys, "doctor", "--fix", "--udev-rules-dir", str(tmp_path))
    assert (tmp_path / "70-wftool.rules").exists()
    assert f"wrote {tmp_path / '70-wftool.rules'}" in err
    assert "  ok udev rules: access to 0483:df11 and 0483:5740 granted" in out
    assert code == (1 if " fail " in out else 0)


# Issue 14: nothing lost, nothing hidden. The FC's settings are read back over its CLI
# and "out of its CLI" means it answers MSP; faults are injected by the faulty transport
# around the real link (tests/fc/faulty_transport.py).


def _eeprom(fc: VirtualFC) -> bytes:
    return (fc.workdir / "eeprom.bin").read_bytes()


DEFAULTS = {"gyro_lpf1_static_hz": "250", "p_pitch": "47", "gyro_lpf2_static_hz": "500"}


def _assert_as_before(fc: VirtualFC, eeprom: bytes) -> None:
    """The FC is out of its CLI (it answers MSP), with the configuration it had: the same
    eeprom.bin, and its CLI reports the settings the tests change at their defaults."""
    assert answers_msp(fc)
    assert _eeprom(fc) == eeprom
    assert fc_settings(fc, *DEFAULTS) == DEFAULTS


@pytest.mark.parametrize(
    "assignments",
    [
        ["gyro_lpf1_static_hz=200", "craft_name=M\xfcller"],
        ["gyro_lpf1_static_hz=200", "craft_name=a\nb"],
        ["gyro_lpf1_static_hz\nfeature MOTOR_STOP=200"],
        ["gyro_lpf1_static_hz=200", "craft_name=" + "x" * 260],
    ],
    ids=["non-ascii", "newline-in-value", "newline-in-name", "longer-than-a-cli-line"],
)
def test_text_the_cli_cannot_carry_is_refused_before_the_fc_is_touched(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path, assignments: list[str]
) -> None:
    eeprom = _eeprom(on_sitl)
    code, _, err = run(capsys, "set", *assignments, "--backup-dir", str(tmp_path / "b"))
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("error: ") and "nothing was changed" in err
    assert not (tmp_path / "b").exists()  # refused before the backup: the FC was not touched
    assert on_sitl.starts == 1
    _assert_as_before(on_sitl, eeprom)


@pytest.mark.parametrize("where", ["under-a-file", "/sys/kernel"])
def test_an_unwritable_backup_dir_is_refused_before_the_fc_is_touched(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path, where: str
) -> None:
    if where == "under-a-file":
        (tmp_path / "a-file").write_text("")
        backup_dir = tmp_path / "a-file" / "backups"
    else:
        backup_dir = Path(where)
        if not backup_dir.is_dir():
            pytest.skip(f"{where} is not a directory here")
    eeprom = _eeprom(on_sitl)
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz=200", "--backup-dir", str(backup_dir))
    assert code == 2, err
    assert err.startswith(f"error: cannot write backups to {backup_dir}: ")
    assert err.endswith("(choose another --backup-dir; the FC was not touched)\n")
    assert err.count("\n") == 1
    assert on_sitl.starts == 1
    _assert_as_before(on_sitl, eeprom)


def test_ctrl_c_during_apply_leaves_the_fc_as_it_was_and_out_of_its_cli(
    on_sitl: VirtualFC,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    inject_faults: InjectFaults,
) -> None:
    # Ctrl-C right after the third `set` went out: two changes are live in RAM, the
    # third is on its way.
    faults = inject_faults(interrupt_at=b"set gyro_lpf2_static_hz")
    eeprom = _eeprom(on_sitl)
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz=200", "p_pitch=50",
                       "gyro_lpf2_static_hz=400", "--backup-dir", str(tmp_path))  # fmt: skip
    assert faults.fired == ["Ctrl-C after b'set gyro_lpf2_static_hz = 400\\n'"]
    assert code == 130
    assert "wftool: interrupted — nothing was saved; the FC drops unsaved changes" in err
    _assert_as_before(on_sitl, eeprom)


def test_an_fc_found_sitting_in_its_cli_is_taken_out_of_it(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # What an interrupted session leaves behind: the CLI open, a change live in RAM.
    session = CliSession.open(on_sitl.url)
    session.set("gyro_lpf1_static_hz", "123")
    session.link.close()
    assert not answers_msp(on_sitl)

    code, out, err = run(capsys, "info")
    assert code == 0, err
    assert out.startswith("BTFL 2026.6.1")
    assert "the FC was sitting in its CLI" in err and "drops any unsaved change" in err
    code, _, err = run(capsys, "set", "p_pitch=55", "--backup-dir", str(tmp_path))
    assert code == 0, err
    assert "sitting in its CLI" not in err
    assert fc_settings(on_sitl, "gyro_lpf1_static_hz", "p_pitch") == {
        "gyro_lpf1_static_hz": "250",
        "p_pitch": "55",
    }


def test_a_link_dropped_at_save_is_not_reported_as_saved(
    on_sitl: VirtualFC,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    inject_faults: InjectFaults,
) -> None:
    faults = inject_faults(drop_at=b"save")  # the FC never gets `save`
    eeprom = _eeprom(on_sitl)
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz=200", "--backup-dir", str(tmp_path))
    assert faults.fired == ["link dropped at b'save\\n'"]
    assert (code, "wftool: saved" in err) == (2, False), err
    assert err.splitlines()[-1].startswith(
        "error: `save` did not reach the FC (it still sat in its CLI) — nothing was saved"
    )
    _assert_as_before(on_sitl, eeprom)


def test_a_save_the_fc_got_before_the_link_dropped_is_confirmed_by_reading_back(
    on_sitl: VirtualFC,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    inject_faults: InjectFaults,
) -> None:
    faults = inject_faults(drop_at=b"save", drop_after_sending=True)
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz=200", "--backup-dir", str(tmp_path))
    assert faults.fired == ["link dropped at b'save\\n'"]
    assert code == 0, err
    assert "saved; waiting" not in err
    assert "saved: the FC did not confirm `save`, but every setting reads back as asked" in err
    on_sitl.restart()  # a cold start: what eeprom.bin holds
    assert fc_settings(on_sitl, "gyro_lpf1_static_hz") == {"gyro_lpf1_static_hz": "200"}


def test_strings_from_the_user_and_the_fc_are_shown_as_text(
    on_sitl: VirtualFC, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    for name in ("Rick[/x]", "Quad[v2]"):
        code, out, err = run(capsys, "set", f"craft_name={name}", "--backup-dir", str(tmp_path))
        assert code == 0, err
        row = next(line for line in out.splitlines() if "craft_name" in line)
        assert [cell.strip() for cell in row.split("│")][4:6] == [name, "ok"], out
    # Betaflight takes any bytes as a board name, once (MSP_SET_BOARD_INFO).
    name = b"[/]\x1b[2J\x1b]8;;x\x07"
    with MspClient.open(on_sitl.url) as msp:
        msp.request(MSP_SET_BOARD_INFO, bytes([len(name)]) + name + b"\x00")
    code, out, err = run(capsys, "info")
    assert code == 0, err
    assert "board [/]\\x1b[2J\\x1b]8;;x\\x07 target SITL" in out
    assert "\x1b" not in out + err


def test_an_error_quoting_the_user_is_one_line_of_text(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, _, err = run(capsys, "info", "--port", "socket://\x1b[2J[/]:x\nerror: forged")
    assert code == 2
    assert err.count("\n") == 1 and "\x1b" not in err
    assert err.startswith("error: cannot open socket://\\x1b[2J[/]:x\\nerror: forged: ")


def test_a_save_confirmed_too_late_is_not_reported_as_nothing_saved(
    on_sitl: VirtualFC,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    inject_faults: InjectFaults,
) -> None:
    # The FC saves at once but its confirmation arrives after the session's 5 s timeout.
    faults = inject_faults(delay_reply_at=b"save", delay_s=6.0)
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz=200", "--backup-dir", str(tmp_path))
    assert faults.fired == ["reply to b'save\\n' held back 6.0 s"]
    assert "nothing was saved" not in err
    assert code == 0, err
    assert "saved: the FC did not confirm `save`, but every setting reads back as asked" in err
    on_sitl.restart()
    assert fc_settings(on_sitl, "gyro_lpf1_static_hz") == {"gyro_lpf1_static_hz": "200"}


def test_ctrl_c_after_save_went_out_is_not_reported_as_nothing_saved(
    on_sitl: VirtualFC,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    inject_faults: InjectFaults,
) -> None:
    faults = inject_faults(interrupt_at=b"save")  # the FC got `save`; then Ctrl-C
    code, _, err = run(capsys, "set", "gyro_lpf1_static_hz=200", "--backup-dir", str(tmp_path))
    assert faults.fired == ["Ctrl-C after b'save\\n'"]
    assert code == 130
    assert "nothing was saved" not in err
    assert "interrupted at `save`: whether the FC saved is not confirmed" in err
    on_sitl.restart()
    assert fc_settings(on_sitl, "gyro_lpf1_static_hz") == {"gyro_lpf1_static_hz": "200"}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["info", "--port", "socket://127.0.0.1:abc"],
         "error: cannot open socket://127.0.0.1:abc: the port must be a number from 1 to 65535, "
         "e.g. socket://127.0.0.1:5761\n"),
        (["info", "--port", "rfc2217://"],
         "error: cannot open rfc2217://: no host in it; expected rfc2217://HOST:PORT, "
         "e.g. rfc2217://127.0.0.1:2217\n"),
        (["set", "gyro_lpf1_static_hz==200"],
         "error: expected NAME=VALUE, got 'gyro_lpf1_static_hz==200'\n"),
    ],
    ids=["socket-port-not-a-number", "rfc2217-without-host", "double-equals"],
)  # fmt: skip
def test_unclear_input_gets_a_clear_one_line_usage_error(
    capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    assert run(capsys, *args)[::2] == (2, message)
