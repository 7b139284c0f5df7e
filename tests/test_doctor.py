"""`wftool doctor` checks and `--fix`, with the rules directory redirected to tmp."""

from __future__ import annotations

from pathlib import Path

import pytest

from wftool import doctor


def test_missing_rules_fail_and_fix_installs_them(tmp_path: Path) -> None:
    rules = tmp_path / "rules.d"
    assert doctor.check_udev_rules((rules,)).status == "fail"
    assert doctor.install_udev_rules(rules, reload=False) == [f"wrote {rules / '70-wftool.rules'}"]
    check = doctor.check_udev_rules((rules,))
    assert (check.status, check.detail) == ("ok", "access to 0483:df11 and 0483:5740 granted")
    assert doctor.install_udev_rules(rules, reload=False) == [
        f"{rules / '70-wftool.rules'} is already up to date"
    ]


def test_rules_file_sorts_before_seat_late_which_applies_uaccess() -> None:
    assert doctor.RULES_FILE_NAME < "73-seat-late.rules"


def test_a_rule_for_only_the_dfu_device_is_not_enough(tmp_path: Path) -> None:
    (tmp_path / "49-stm32.rules").write_text(
        'SUBSYSTEMS=="usb", ATTRS{idVendor}=="0483", ATTRS{idProduct}=="df11", MODE="0664", '
        'GROUP="plugdev"\n'
    )
    check = doctor.check_udev_rules((tmp_path,))
    assert (check.status, check.detail) == ("fail", "no rule gives users access to 0483:5740")


def test_modemmanager_is_flagged_until_the_rules_tell_it_to_ignore_the_fc(tmp_path: Path) -> None:
    proc = tmp_path / "proc"
    (proc / "4242").mkdir(parents=True)
    (proc / "4242" / "comm").write_text("ModemManager\n")
    (proc / "self").mkdir()
    rules = tmp_path / "rules.d"
    assert doctor.check_modemmanager(proc, (rules,)).status == "warn"
    doctor.install_udev_rules(rules, reload=False)
    assert (
        doctor.check_modemmanager(proc, (rules,)).detail == "running, but told to ignore 0483:5740"
    )
    (proc / "4242" / "comm").write_text("bash\n")
    assert doctor.check_modemmanager(proc, (rules,)).detail == "not running"


def _program(directory: Path, name: str, output: str) -> None:
    program = directory / name
    program.write_text(f"#!/bin/sh\necho '{output}'\n")
    program.chmod(0o755)


def test_dfu_util_version_is_reported(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    _program(tmp_path, "dfu-util", "dfu-util 0.11")  # first line of the real `--version`
    monkeypatch.setenv("PATH", str(tmp_path))
    assert doctor.check_dfu_util() == doctor.Check("dfu-util", "ok", "dfu-util 0.11")


def test_missing_tools_fail(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    assert doctor.check_dfu_util().status == "fail"
    assert doctor.check_toolchain().status == "fail"


def test_toolchain_version_is_compared_with_betaflights(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    gcc = tmp_path / "arm-none-eabi-gcc"  # Debian's 12.2, as `-dumpversion` answers
    gcc.write_text("#!/bin/sh\necho 12.2.1\n")
    gcc.chmod(0o755)
    monkeypatch.setenv("PATH", str(tmp_path))
    check = doctor.check_toolchain()
    assert check.status == "warn"
    assert check.detail.startswith("arm-none-eabi-gcc 12.2.1; the pinned Betaflight expects 13.3.1")


def test_group_membership() -> None:
    assert doctor.check_groups({"dialout", "plugdev"}).status == "ok"
